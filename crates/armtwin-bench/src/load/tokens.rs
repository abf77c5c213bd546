//! armtwin's liveliness tokens, one per tracked robot: watched as they come and go, and awaited
//! until a given number are visible.

use std::collections::HashSet;
use std::sync::{Arc, Mutex, PoisonError};
use std::thread;
use std::time::{Duration, Instant};

use zenoh::Wait;
use zenoh::pubsub::Subscriber;
use zenoh::sample::SampleKind;
use zenoh::session::Session;

use super::{Load, LoadError};
use crate::net;

/// How long the wait for armtwin's liveliness tokens goes on without any new one.
const TRACKING_STALL: Duration = Duration::from_secs(30);

impl Load {
    /// armtwin declares a newly tracked robot's liveliness token on its control thread, after
    /// the robot's first sample has been answered, every new robot's token before any robot's
    /// route caches (Zenoh's declarations cost O(robots) each). The echo declares everything
    /// before it reports ready. So that both are measured tracking every robot, this waits until
    /// `robots` tokens are visible. Returns whether it waited (only armtwin has tokens).
    pub(super) fn wait_for_tracking(&self, robots: usize) -> Result<bool, LoadError> {
        if self.tokens.is_none() || robots == 0 {
            return Ok(false);
        }
        self.await_tokens(robots)?;
        Ok(true)
    }
    /// Waits until `robots` liveliness tokens are visible, in whatever order they are declared
    /// (a restarted armtwin declares its restored robots' tokens in its own order); fails if
    /// their count stops growing for [`TRACKING_STALL`].
    pub(super) fn await_tokens(&self, robots: usize) -> Result<(), LoadError> {
        let tokens = self
            .tokens
            .as_ref()
            .ok_or_else(|| LoadError::NoAnswer("only armtwin declares tokens".to_owned()))?;
        let (mut seen, mut progress, mut reported) = (0, Instant::now(), Instant::now());
        loop {
            let now_seen = tokens.live();
            if now_seen >= robots {
                eprintln!("load: armtwin tracks {now_seen} robots (liveliness tokens)");
                return Ok(());
            }
            if now_seen > seen {
                seen = now_seen;
                progress = Instant::now();
            } else if progress.elapsed() >= TRACKING_STALL {
                return Err(LoadError::NoAnswer(format!(
                    "armtwin declared {seen} of {robots} robots' liveliness tokens, then none for {} s",
                    TRACKING_STALL.as_secs()
                )));
            }
            if reported.elapsed() >= Duration::from_secs(5) {
                reported = Instant::now();
                eprintln!("load: armtwin has declared {seen} of {robots} robots");
            }
            thread::sleep(Duration::from_millis(10));
        }
    }
}

/// The liveliness tokens of armtwin's robots, kept by a liveliness subscriber that is told of
/// those already declared and then of each one declared or undeclared. Watching them costs the
/// system under test one message per token; asking for all of them again and again (a
/// liveliness `get`) would cost it and this process work in proportion to the tokens each time.
pub(super) struct Tokens {
    live: Arc<Mutex<HashSet<String>>>,
    _subscriber: Subscriber<()>,
}

impl Tokens {
    pub(super) fn watch(session: &Session) -> Result<Self, LoadError> {
        let live = Arc::new(Mutex::new(HashSet::new()));
        let kept = Arc::clone(&live);
        let subscriber = session
            .liveliness()
            .declare_subscriber(net::every_robot(net::ALIVE))
            .history(true)
            .callback(move |sample| {
                let mut live = kept.lock().unwrap_or_else(PoisonError::into_inner);
                match sample.kind() {
                    SampleKind::Put => live.insert(sample.key_expr().as_str().to_owned()),
                    SampleKind::Delete => live.remove(sample.key_expr().as_str()),
                };
            })
            .wait()?;
        Ok(Self {
            live,
            _subscriber: subscriber,
        })
    }

    /// Tokens declared now.
    pub(super) fn live(&self) -> usize {
        self.live
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .len()
    }
}
