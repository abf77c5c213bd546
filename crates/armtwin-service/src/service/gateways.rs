//! The gateways' liveliness tokens of this instance's robots (`<prefix>/gateway/streaming/<robot>`
//! and `<prefix>/gateway/waiting/<robot>`), heard through one liveliness subscriber per kind and
//! kept as one small entry per robot, for `/metrics`' `armtwin_gateway_streaming`.
//!
//! Robot ids come from whoever declares a token on the mesh: at most `capacity` entries are kept
//! (the fleet's own bound, `[service] max_robots`), ids outside `[service] robots` are not kept,
//! and an entry whose tokens are gone is dropped once its robot is neither configured nor
//! tracked ([`GatewayTokens::read`]). Must not touch the fleet, nor block in a callback beyond
//! the entries' lock.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use tracing::{debug, warn};
use zenoh::key_expr::KeyExpr;
use zenoh::sample::{Sample, SampleKind};
use zenoh::session::Session;

use super::error::ServiceError;
use armtwin_mesh::keys::{KeySpace, Stream};

/// Which of a robot's gateway tokens are declared now.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Tokens {
    streaming: bool,
    waiting: bool,
}

/// The robots' gateway tokens as heard so far.
pub(super) struct GatewayTokens {
    entries: Mutex<HashMap<Arc<str>, Tokens>>,
    capacity: usize,
    /// Set once a token was left out for a full table, so that is logged once.
    overflow_logged: AtomicBool,
}

impl GatewayTokens {
    /// An empty table of at most `capacity` robots.
    pub(super) fn new(capacity: usize) -> Self {
        Self {
            entries: Mutex::new(HashMap::new()),
            capacity,
            overflow_logged: AtomicBool::new(false),
        }
    }

    /// Robot `id`'s `kind` token declared (`present`) or gone.
    fn heard(&self, id: &str, kind: Stream, present: bool) {
        let mut entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(tokens) = entries.get_mut(id) {
            tokens.set(kind, present);
            return;
        }
        if !present {
            return;
        }
        if entries.len() >= self.capacity {
            // A robot whose gateway is gone makes room for one whose gateway is here.
            let gone = entries
                .iter()
                .find(|(_, tokens)| !tokens.streaming && !tokens.waiting)
                .map(|(id, _)| Arc::clone(id));
            let Some(gone) = gone else {
                if !self.overflow_logged.swap(true, Ordering::Relaxed) {
                    warn!(
                        robot = id,
                        capacity = self.capacity,
                        "more robots hold gateway tokens than the fleet may track \
                         (service.max_robots): the others' are not exported"
                    );
                }
                return;
            };
            entries.remove(&gone);
        }
        let mut tokens = Tokens::default();
        tokens.set(kind, true);
        entries.insert(Arc::from(id), tokens);
    }

    /// Every robot with a gateway token declared, or whose robot `known` says is configured or
    /// tracked (its gateway went away: not streaming), in id order, with whether its gateway
    /// streams; the others are forgotten.
    pub(super) fn read(&self, known: impl Fn(&str) -> bool) -> Vec<(Arc<str>, bool)> {
        let mut entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        entries.retain(|id, tokens| tokens.streaming || tokens.waiting || known(id));
        let mut rows: Vec<(Arc<str>, bool)> = entries
            .iter()
            .map(|(id, tokens)| (Arc::clone(id), tokens.streaming))
            .collect();
        drop(entries);
        rows.sort_unstable_by(|a, b| a.0.cmp(&b.0));
        rows
    }
}

impl Tokens {
    fn set(&mut self, kind: Stream, present: bool) {
        match kind {
            Stream::GatewayStreaming => self.streaming = present,
            _ => self.waiting = present,
        }
    }
}

/// Subscribes to the gateway tokens of the robots of `shard` (history included: tokens declared
/// before this instance started count), each heard into `tokens`.
pub(super) async fn watch_gateways(
    session: &Session,
    keys: &KeySpace,
    shard: &KeyExpr<'static>,
    tokens: &Arc<GatewayTokens>,
) -> Result<Vec<zenoh::pubsub::Subscriber<()>>, ServiceError> {
    let mut subscribers = Vec::with_capacity(2);
    for kind in [Stream::GatewayStreaming, Stream::GatewayWaiting] {
        let key = KeyExpr::try_from(keys.key(kind, shard.as_str()))?;
        let (tokens, keys) = (Arc::clone(tokens), keys.clone());
        let subscriber = session
            .liveliness()
            .declare_subscriber(key)
            .history(true)
            .callback(move |sample: Sample| {
                let Ok(id) = keys.robot_of(kind, sample.key_expr().as_str()) else {
                    debug!(key = %sample.key_expr(), "a gateway token that names no robot: ignored");
                    return;
                };
                tokens.heard(id, kind, sample.kind() == SampleKind::Put);
            })
            .await?;
        subscribers.push(subscriber);
    }
    Ok(subscribers)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn streaming(tokens: &GatewayTokens, known: &[&str]) -> Vec<(String, bool)> {
        tokens
            .read(|id| known.contains(&id))
            .into_iter()
            .map(|(id, streaming)| (id.to_string(), streaming))
            .collect()
    }

    #[test]
    fn a_gateway_streams_waits_and_goes_away() {
        let tokens = GatewayTokens::new(8);
        tokens.heard("r1", Stream::GatewayWaiting, true);
        assert_eq!(streaming(&tokens, &[]), [("r1".to_owned(), false)]);
        tokens.heard("r1", Stream::GatewayStreaming, true);
        tokens.heard("r1", Stream::GatewayWaiting, false);
        assert_eq!(streaming(&tokens, &[]), [("r1".to_owned(), true)]);
        tokens.heard("r1", Stream::GatewayStreaming, false);
        // Gone, and the robot still tracked: shown as not streaming.
        assert_eq!(streaming(&tokens, &["r1"]), [("r1".to_owned(), false)]);
        // Gone, and the robot neither configured nor tracked: forgotten.
        assert_eq!(streaming(&tokens, &[]), []);
        // A deletion of a token never heard adds nothing.
        tokens.heard("r2", Stream::GatewayStreaming, false);
        assert_eq!(streaming(&tokens, &["r2"]), []);
    }

    #[test]
    fn the_table_is_bounded_and_a_gone_gateway_makes_room() {
        let tokens = GatewayTokens::new(2);
        tokens.heard("b", Stream::GatewayStreaming, true);
        tokens.heard("a", Stream::GatewayStreaming, true);
        tokens.heard("c", Stream::GatewayStreaming, true);
        assert_eq!(
            streaming(&tokens, &["a", "b", "c"]),
            [("a".to_owned(), true), ("b".to_owned(), true)]
        );
        tokens.heard("a", Stream::GatewayStreaming, false);
        tokens.heard("c", Stream::GatewayWaiting, true);
        assert_eq!(
            streaming(&tokens, &["a", "b", "c"]),
            [("b".to_owned(), true), ("c".to_owned(), false)]
        );
    }
}
