//! A Zenoh session's configuration from a `[zenoh]` section, publisher aggregation, and the
//! bounded steps of a teardown.
//!
//! Must not open anything itself or know what the session carries.

use std::future::IntoFuture;
use std::time::Duration;

use thiserror::Error;
use tracing::warn;

use crate::zenoh_section::{Origin, ZenohSection, without_source_location};

/// How long each teardown step may take.
pub const TEARDOWN_STEP: Duration = Duration::from_secs(5);

/// Why a session could not be configured or opened.
#[derive(Debug, Error)]
pub enum MeshError {
    /// The Zenoh configuration is invalid.
    #[error("zenoh configuration: {0}")]
    Config(String),
    /// Zenoh failed (opening the session, declaring, …).
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
}

/// Builds the Zenoh configuration of a `[zenoh]` section (the command line's flags already
/// applied, [`ZenohSection::overridden`]): the one place every armtwin session gets its
/// configuration from. The section's `[zenoh] file` first; then its mode, multicast scouting and
/// the endpoint lists the file does not set itself ([`ZenohSection::layered`]); its `cfg` entries
/// last, so they win.
pub fn zenoh_config_of(section: &ZenohSection) -> Result<zenoh::Config, MeshError> {
    let mut zenoh = match &section.file {
        Some(path) => zenoh::Config::from_file(path)
            .map_err(|e| MeshError::Config(format!("{}: {e}", path.display())))?,
        None => zenoh::Config::default(),
    };
    let json = |value: &[String]| serde_json::to_string(value).unwrap_or_else(|_| "[]".to_owned());
    let mut inserts = vec![
        ("mode", format!("\"{}\"", section.mode)),
        (
            "scouting/multicast/enabled",
            section.multicast_scouting.to_string(),
        ),
    ];
    // A list the `[zenoh] file` sets itself stays as the file has it.
    if !matches!(section.origins.listen, Origin::ZenohFile { .. }) {
        inserts.push(("listen/endpoints", json(&section.listen)));
    }
    if !matches!(section.origins.connect, Origin::ZenohFile { .. }) {
        inserts.push(("connect/endpoints", json(&section.connect)));
    }
    for (key, value) in inserts {
        zenoh
            .insert_json5(key, &value)
            .map_err(|e| MeshError::Config(format!("{key} = {value}: {e}")))?;
    }
    for insert in &section.cfg {
        if let Err(e) = zenoh.insert_json5(&insert.key, &insert.value) {
            // Zenoh's message is the parser's error in debug form (an escaped excerpt of the
            // value, then the reason after `= `) followed by Zenoh's source location.
            let message = e.to_string();
            let reason = message
                .split_once("msg: \"")
                .and_then(|(_, rest)| rest.split_once('"'))
                .map_or(message.as_str(), |(msg, _)| msg);
            let reason = reason.rsplit_once("= ").map_or(reason, |(_, last)| last);
            let reason = without_source_location(reason);
            let problem = if zenoh.get_json(&insert.key).is_err() {
                "Zenoh's configuration has no such key".to_owned()
            } else {
                format!("not a value this key takes: {reason}")
            };
            return Err(MeshError::Config(format!(
                "cannot set '{}' to '{}': {problem}",
                insert.key, insert.value
            )));
        }
    }
    Ok(zenoh)
}

/// Aggregates this session's publishers under `key_exprs` (Zenoh's `aggregation/publishers`),
/// unless the configuration already names publishers to aggregate: then the operator's choice
/// stands. Every publisher declared without it asks the mesh for its key's subscribers, a
/// reliable message to every peer that each answers; aggregated, the first publisher under a key
/// expression asks for all of them and the others ask nothing, so a fleet's publishers cost only
/// their local key declarations and no subscriber's link has to carry them.
pub fn aggregate_publishers(
    zenoh: &mut zenoh::Config,
    key_exprs: &[String],
) -> Result<(), MeshError> {
    let configured = zenoh
        .get_json("aggregation/publishers")
        .map_err(|e| MeshError::Config(format!("aggregation/publishers: {e}")))?;
    let configured: Vec<String> = serde_json::from_str(&configured).unwrap_or_default();
    if !configured.is_empty() || key_exprs.is_empty() {
        return Ok(());
    }
    let value = serde_json::to_string(key_exprs).unwrap_or_else(|_| "[]".to_owned());
    zenoh
        .insert_json5("aggregation/publishers", &value)
        .map_err(|e| MeshError::Config(format!("aggregation/publishers = {value}: {e}")))
}

/// Awaits one teardown step for at most `limit`. `None`, with a warning naming the step, when it
/// did not finish in time: the step is abandoned and the teardown goes on, so a peer that stopped
/// answering cannot hold a shutdown forever.
pub async fn bounded<T>(
    step: &str,
    limit: Duration,
    future: impl IntoFuture<Output = T>,
) -> Option<T> {
    let outcome = tokio::time::timeout(limit, future).await.ok();
    if outcome.is_none() {
        warn!(
            step,
            limit_s = limit.as_secs_f64(),
            "teardown step did not finish in time: abandoned"
        );
    }
    outcome
}

/// Closes `session` within [`TEARDOWN_STEP`]: Zenoh's error if it failed, `Ok` if it closed or
/// took too long (then abandoned, and logged by [`bounded`]).
///
/// # Errors
/// Zenoh's, when closing failed.
pub async fn close_session(session: &zenoh::Session) -> zenoh::Result<()> {
    bounded("closing the session", TEARDOWN_STEP, session.close())
        .await
        .unwrap_or(Ok(()))
}

/// The stamp (s) of a message without its own: the Zenoh timestamp, else the arrival time. Read
/// only for such a message where that can be told apart: most carry `t`, and a clock read per
/// message adds up.
#[must_use]
pub fn transport_stamp_s(sample: &zenoh::sample::Sample) -> f64 {
    sample.timestamp().map_or_else(
        || {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64())
        },
        |t| t.get_time().as_secs_f64(),
    )
}
