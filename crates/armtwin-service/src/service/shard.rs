//! The shard claim: an instance claims `[service] robots` on the mesh before it takes input,
//! and refuses to start over another instance's overlapping claim.
//!
//! Must not touch the fleet.

use std::time::Duration;

use tracing::{debug, info, warn};
use zenoh::Wait;
use zenoh::bytes::Encoding;
use zenoh::key_expr::KeyExpr;
use zenoh::sample::Locality;
use zenoh::session::Session;

use super::error::ServiceError;
use armtwin_mesh::keys::KeySpace;

/// How long an instance waits for the others' shard claims at start.
const SHARD_CLAIM_WAIT: Duration = Duration::from_secs(2);

/// Claims `[service] robots` on the mesh: a queryable `<prefix>/shards/<zid>` answers this
/// instance's key expression, declared before asking the others' so that of two instances
/// starting together at least the later one sees the earlier. Fails when another instance's
/// key expression intersects this one's. Each answer carries `service()`, the instance's totals
/// at the time.
pub(super) async fn claim_shard(
    session: &Session,
    keys: &KeySpace,
    shard: &KeyExpr<'static>,
    service: impl Fn() -> serde_json::Value + Send + Sync + 'static,
) -> Result<zenoh::query::Queryable<()>, ServiceError> {
    let zid = session.zid().to_string();
    let claim_key = KeyExpr::try_from(keys.shard_claim(&zid))?;
    let reply_key = claim_key.clone();
    let shard_text = shard.as_str().to_owned();
    let queryable = session
        .declare_queryable(claim_key)
        .callback(move |query| {
            let claim =
                serde_json::json!({ "robots": shard_text, "zid": zid, "service": service() })
                    .to_string();
            if let Err(e) = query
                .reply(reply_key.clone(), claim)
                .encoding(Encoding::APPLICATION_JSON)
                .wait()
            {
                warn!(error = %e, "shard claim reply failed");
            }
        })
        .await?;
    let replies = session
        .get(keys.every_shard_claim())
        .allowed_destination(Locality::Remote)
        .timeout(SHARD_CLAIM_WAIT)
        .await?;
    while let Ok(reply) = replies.recv_async().await {
        let Ok(sample) = reply.result() else { continue };
        let text = sample.payload().try_to_string().unwrap_or_default();
        let claim: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
        let other = claim.get("robots").and_then(serde_json::Value::as_str);
        let Some(other_key) = other.and_then(|other| KeyExpr::try_from(other).ok()) else {
            warn!(key = %sample.key_expr(), "a shard claim that names no key expression: ignored");
            continue;
        };
        if other_key.intersects(shard) {
            let zid = claim.get("zid").and_then(serde_json::Value::as_str);
            return Err(ServiceError::ShardOverlap {
                own: shard.to_string(),
                other: other_key.to_string(),
                zid: zid.unwrap_or("?").to_owned(),
            });
        }
        debug!(other = %other_key, "another instance's robots, disjoint from this one's");
    }
    info!(robots = %shard, "robots claimed");
    Ok(queryable)
}
