//! What the service end-to-end tests share: the outputs a client collects.
#![allow(
    clippy::expect_used,
    reason = "a helper of a test that fails an expectation fails the test"
)]

use std::time::Duration;

use serde_json::Value;
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
