//! What the service end-to-end tests share: the service in this process, a client of it and the
//! outputs that client collects, and the harness that holds the three.

use std::time::Duration;

use serde_json::Value;
use zenoh::Session;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::{Sample, SampleKind};

/// How long to wait for an expected message.
pub const RECEIVE_LIMIT: Duration = Duration::from_secs(30);

/// armtwin's outputs as a client's `twin/**` subscriber receives them, decoded as JSON, in order.
pub struct Outputs {
    subscriber: Subscriber<FifoChannelHandler<Sample>>,
    /// Every output so far: key and message.
    pub received: Vec<(String, Value)>,
}

impl Outputs {
    /// Collects what `subscriber` receives.
    pub fn new(subscriber: Subscriber<FifoChannelHandler<Sample>>) -> Self {
        Self {
            subscriber,
            received: Vec::new(),
        }
    }

    /// Receives until `done` holds for the messages received so far. `done` is evaluated once
    /// per burst (after draining what has arrived), so long streams stay linear.
    pub async fn receive_until(&mut self, what: &str, done: impl Fn(&[(String, Value)]) -> bool) {
        let deadline = tokio::time::Instant::now() + RECEIVE_LIMIT;
        while !done(&self.received) {
            let left = deadline.saturating_duration_since(tokio::time::Instant::now());
            let first = tokio::time::timeout(left, self.subscriber.recv_async())
                .await
                .unwrap_or_else(|_| {
                    panic!(
                        "timed out waiting for {what}; received {} messages: {:?}",
                        self.received.len(),
                        self.received.iter().rev().take(5).collect::<Vec<_>>()
                    )
                })
                .expect("subscriber open");
            self.keep(&first);
            while let Ok(Some(sample)) = self.subscriber.try_recv() {
                self.keep(&sample);
            }
        }
    }

    fn keep(&mut self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        // The client's own inputs come back to it too; only outputs are collected.
        if sample.kind() != SampleKind::Put
            || key.starts_with("twin/joints/")
            || key.starts_with("twin/measured/")
        {
            return;
        }
        let value: Value = serde_json::from_slice(&sample.payload().to_bytes())
            .unwrap_or_else(|e| panic!("output on {key} is not JSON: {e}"));
        self.received.push((key.to_owned(), value));
    }

    /// The messages received on `key`, in order.
    pub fn on(&self, key: &str) -> Vec<&Value> {
        self.received
            .iter()
            .filter(|(k, _)| k == key)
            .map(|(_, v)| v)
            .collect()
    }
}

/// A loopback port nothing listens on now.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|listener| listener.local_addr())
        .map(|address| address.port())
        .expect("a free loopback port")
}

/// A test client's Zenoh configuration: a peer of `endpoint` alone.
pub fn client_config(endpoint: &str) -> zenoh::Config {
    let mut config = zenoh::Config::default();
    for (key, value) in [
        ("mode", "\"peer\"".to_owned()),
        ("connect/endpoints", format!("[\"{endpoint}\"]")),
        ("listen/endpoints", "[]".to_owned()),
        ("scouting/multicast/enabled", "false".to_owned()),
    ] {
        config.insert_json5(key, &value).expect("client config");
    }
    config
}

/// A client peer of the service at `endpoint` (loopback, no scouting), with its collector of
/// armtwin's outputs.
pub async fn connect_client(endpoint: &str) -> (zenoh::Session, Outputs) {
    let client = zenoh::open(client_config(endpoint))
        .await
        .expect("client session");
    let subscriber = client
        .declare_subscriber("twin/**")
        .with(zenoh::handlers::FifoChannel::new(200_000))
        .await
        .expect("output subscriber");
    (client, Outputs::new(subscriber))
}

/// Waits until a remote subscriber matches `key` (the service's: the client's own `twin/**`
/// matches too, so only remote ones count), so nothing put on it is lost.
pub async fn wait_for_subscriber(client: &zenoh::Session, key: &str) {
    let probe = client
        .declare_publisher(key.to_owned())
        .allowed_destination(zenoh::sample::Locality::Remote)
        .await
        .expect("probe publisher");
    let deadline = tokio::time::Instant::now() + RECEIVE_LIMIT;
    while !probe.matching_status().await.expect("matching").matching() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "no subscriber for {key}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    probe.undeclare().await.expect("undeclare probe");
}

/// `armtwin serve` running in this process, on a loopback port of its own.
pub struct Service {
    /// Where it listens (`tcp/127.0.0.1:<port>`).
    pub endpoint: String,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    server: Option<
        tokio::task::JoinHandle<
            Result<armtwin_service::service::ServeReport, armtwin_service::service::ServiceError>,
        >,
    >,
}

impl Service {
    /// Starts the service with the configuration `config_for` makes for its endpoint; returns
    /// once it listens.
    pub async fn start(
        config_for: impl FnOnce(&str) -> armtwin_service::config::ServiceConfig,
    ) -> Self {
        let port = free_port();
        let endpoint = format!("tcp/127.0.0.1:{port}");
        let config = config_for(&endpoint);
        let (shutdown_tx, shutdown_rx) = tokio::sync::oneshot::channel::<()>();
        let http = dashboard_door(&config);
        let server = tokio::spawn(armtwin_service::service::serve(
            config,
            Some(http),
            None,
            async {
                let _ = shutdown_rx.await;
            },
        ));
        let deadline = tokio::time::Instant::now() + RECEIVE_LIMIT;
        while tokio::net::TcpStream::connect(("127.0.0.1", port))
            .await
            .is_err()
        {
            assert!(
                tokio::time::Instant::now() < deadline,
                "the service never listened"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        Self {
            endpoint,
            shutdown: Some(shutdown_tx),
            server: Some(server),
        }
    }

    /// Shuts it down (as SIGINT would) and returns its report.
    pub async fn stop(&mut self) -> armtwin_service::service::ServeReport {
        if let Some(shutdown) = self.shutdown.take() {
            let _ = shutdown.send(());
        }
        let server = self.server.take().expect("running");
        tokio::time::timeout(RECEIVE_LIMIT, server)
            .await
            .expect("the service stops in time")
            .expect("the service task")
            .expect("the service ran")
    }
}

/// The service in this process, and a client peer of it that collects its outputs.
pub struct Harness {
    pub service: Service,
    pub client: Session,
    pub outputs: Outputs,
}

impl Harness {
    /// The service with the configuration `config_for` makes for its endpoint, and a client whose
    /// publishers on `probe_keys` the service's subscribers match; returns once the service has
    /// seen the client's subscriber (one state query's round trip).
    pub async fn start(
        config_for: impl FnOnce(&str) -> armtwin_service::config::ServiceConfig,
        probe_keys: &[&str],
    ) -> Self {
        let service = Service::start(config_for).await;
        let (client, outputs) = connect_client(&service.endpoint).await;
        for key in probe_keys {
            wait_for_subscriber(&client, key).await;
        }
        let harness = Self {
            service,
            client,
            outputs,
        };
        harness.round_trip().await;
        harness
    }

    /// A state query, answered after everything the client sent before it (one ordered link):
    /// the robots that answered, sorted.
    pub async fn round_trip(&self) -> Vec<String> {
        let replies = self.client.get("twin/state/**").await.expect("get");
        let mut robots = Vec::new();
        while let Ok(reply) = tokio::time::timeout(RECEIVE_LIMIT, replies.recv_async())
            .await
            .expect("state query answered")
        {
            let sample = reply.result().expect("state");
            let state: Value = serde_json::from_slice(&sample.payload().to_bytes()).expect("json");
            robots.push(state["robot"].as_str().expect("robot").to_owned());
        }
        robots.sort();
        robots
    }

    /// Puts `payload` as JSON text.
    pub async fn put(&self, key: &str, payload: &Value) {
        self.client
            .put(key, payload.to_string())
            .await
            .expect("put");
    }

    /// Puts raw bytes, blocking rather than dropped under congestion: a large payload is
    /// fragmented, and on a loaded machine a dropped fragment would lose the message the test
    /// counts on.
    pub async fn put_raw(&self, key: &str, payload: Vec<u8>) {
        self.client
            .put(key, payload)
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .await
            .expect("put");
    }

    /// Puts raw bytes with an attachment (as `rmw_zenoh` does).
    pub async fn put_attached(&self, key: &str, payload: &[u8], attachment: Option<Vec<u8>>) {
        self.client
            .put(key, payload.to_vec())
            .attachment(attachment)
            .await
            .expect("put");
    }

    /// Every reply to a query of `selector` (with `payload` as JSON): key and message, or the
    /// error's message.
    pub async fn get(
        &self,
        selector: &str,
        payload: Option<Value>,
    ) -> Vec<Result<(String, Value), Value>> {
        let mut get = self.client.get(selector);
        if let Some(payload) = payload {
            get = get.payload(payload.to_string());
        }
        let replies = get.await.expect("get");
        let mut out = Vec::new();
        while let Ok(reply) = tokio::time::timeout(RECEIVE_LIMIT, replies.recv_async())
            .await
            .expect("replies end in time")
        {
            match reply.result() {
                Ok(sample) => out.push(Ok((
                    sample.key_expr().as_str().to_owned(),
                    serde_json::from_slice(&sample.payload().to_bytes()).expect("json reply"),
                ))),
                Err(error) => out.push(Err(
                    serde_json::from_slice(&error.payload().to_bytes()).expect("json error")
                )),
            }
        }
        out
    }

    pub async fn receive_until(&mut self, what: &str, done: impl Fn(&[(String, Value)]) -> bool) {
        self.outputs.receive_until(what, done).await;
    }

    pub fn on(&self, key: &str) -> Vec<&Value> {
        self.outputs.on(key)
    }

    /// The last metrics message of `robot` received so far.
    pub fn last_metrics(&self, robot: &str) -> Option<&Value> {
        self.on(&format!("twin/metrics/{robot}")).last().copied()
    }

    /// Stops the service (as SIGINT would) and returns its report.
    pub async fn stop(&mut self) -> armtwin_service::service::ServeReport {
        self.service.stop().await
    }
}

/// The dashboard as the service's HTTP side, as `armtwin serve` hands it in.
pub fn dashboard_door(
    config: &armtwin_service::config::ServiceConfig,
) -> Box<dyn armtwin_view::HttpDoor> {
    Box::new(armtwin_dashboard::DashboardDoor::new(
        config.http_access.clone(),
    ))
}
