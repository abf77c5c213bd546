//! `armtwin replay`: publishes a recording to the mesh exactly as a gateway would — one joint
//! message per row (with the row's measured pose embedded) on `<prefix>/joints/<robot>`, at the
//! recorded pace, scaled, or as fast as the transport takes it.
//!
//! Owns pacing and publishing only; rows become messages in [`armtwin_codec::recording`], the
//! same messages `validate` decodes offline. A line that does not split into the header's columns
//! is published as its raw text, so the service rejects and counts it as validation does.

use std::future::Future;
use std::time::Duration;

use tokio::time::Instant;
use tracing::{info, warn};
use zenoh::Wait;
use zenoh::qos::CongestionControl;

use armtwin_codec::recording::{self, Recording};
use armtwin_mesh::keys::{KeyPrefixError, KeySpace, Stream};
use armtwin_mesh::zenoh_section::ZenohSection;
use armtwin_mesh::{MeshError, TEARDOWN_STEP, bounded, close_session, zenoh_config_of};

/// How long to wait for a subscriber (the service) before giving up.
const WAIT_FOR_SUBSCRIBER: Duration = Duration::from_secs(10);

/// How long to wait at the end for the service to take what was published.
const DRAIN_LIMIT: Duration = Duration::from_secs(120);

/// Replay options.
#[derive(Debug, Clone)]
pub struct ReplaySettings {
    /// How to join the mesh.
    pub zenoh: ZenohSection,
    /// Key prefix (`twin`).
    pub key_prefix: String,
    /// The robot id to publish as.
    pub robot: String,
    /// Playback speed relative to the recording (`None`: as fast as possible).
    pub speed: Option<f64>,
}

/// What a replay sent.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReplayReport {
    /// Messages published.
    pub published: u64,
    /// Of those, malformed lines sent as raw text.
    pub malformed: u64,
    /// Whether the replay was interrupted before the end.
    pub interrupted: bool,
}

/// Waits until the service has taken every message published so far: closing the session drops
/// whatever its transmit queue still holds, and a service slower than the replay leaves some there.
/// A query for the robot's state travels behind the puts on the same link and is answered after
/// them, so its final reply is a barrier. Without an `armtwin serve` answering it returns at once.
async fn drain(session: &zenoh::Session, keys: &KeySpace, settings: &ReplaySettings) {
    let key = keys.key(Stream::State, &settings.robot);
    match session.get(&key).timeout(DRAIN_LIMIT).await {
        Ok(replies) => while replies.recv_async().await.is_ok() {},
        Err(e) => {
            warn!(error = %e, %key, "could not wait for the service to take every message");
        }
    }
}

/// Why a replay stopped.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The session could not be configured or opened.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// Zenoh failed (declaring, publishing, …).
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
    /// `--prefix` is not a plain key.
    #[error(transparent)]
    KeyPrefix(#[from] KeyPrefixError),
    /// No subscriber (no service) took the recording's key in time.
    #[error(
        "nobody subscribes to {key} after {waited_s} s: is `armtwin serve` running and reachable ({connect:?})?"
    )]
    NoSubscriber {
        /// The joints key the recording goes to.
        key: String,
        /// How long the replay waited.
        waited_s: u64,
        /// The endpoints it connected to.
        connect: Vec<String>,
    },
}

/// Publishes `recording` with source times `times_s` until done or `shutdown` completes, calling
/// `progress` with the number of messages published.
pub async fn replay(
    recording: &Recording,
    times_s: &[f64],
    settings: &ReplaySettings,
    shutdown: impl Future<Output = ()>,
    mut progress: impl FnMut(usize),
) -> Result<ReplayReport, ReplayError> {
    // A prefix that is no plain key would fail at the publisher's declaration: fail before.
    let keys = KeySpace::of_prefix(&settings.key_prefix)?;
    let session = zenoh::open(zenoh_config_of(&settings.zenoh)?).await?;
    let key = keys.key(Stream::Joints, &settings.robot);
    let publisher = session
        .declare_publisher(key.clone())
        .congestion_control(CongestionControl::Block)
        .await?;
    let deadline = Instant::now() + WAIT_FOR_SUBSCRIBER;
    while !publisher.matching_status().await?.matching() {
        if Instant::now() >= deadline {
            let _ = close_session(&session).await;
            return Err(ReplayError::NoSubscriber {
                key,
                waited_s: WAIT_FOR_SUBSCRIBER.as_secs(),
                connect: settings.zenoh.connect.clone(),
            });
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    info!(%key, rows = recording.entries.len(), "replaying");
    let mut report = ReplayReport::default();
    let start = Instant::now();
    let first_s = times_s.first().copied().unwrap_or(0.0);
    tokio::pin!(shutdown);
    for (index, (entry, &t_s)) in recording.entries.iter().zip(times_s).enumerate() {
        let due = settings.speed.and_then(|speed| {
            let delay = Duration::try_from_secs_f64(((t_s - first_s) / speed).max(0.0)).ok()?;
            start.checked_add(delay)
        });
        if let Some(due) = due {
            tokio::select! {
                () = tokio::time::sleep_until(due) => {}
                () = &mut shutdown => { report.interrupted = true; break; }
            }
        } else if index % 1024 == 0 {
            // Let Ctrl-C through even at full rate.
            if tokio::time::timeout(Duration::ZERO, &mut shutdown)
                .await
                .is_ok()
            {
                report.interrupted = true;
                break;
            }
        }
        if entry.is_err() {
            report.malformed += 1;
        }
        publisher.put(recording::payload(entry, t_s)).wait()?;
        report.published += 1;
        progress(index + 1);
    }
    // The query's own timeout ends the wait; the bound covers a session that stops answering.
    bounded(
        "waiting for the service to take every message",
        DRAIN_LIMIT + TEARDOWN_STEP,
        drain(&session, &keys, settings),
    )
    .await;
    if let Some(result) = bounded(
        "undeclaring the publisher",
        TEARDOWN_STEP,
        publisher.undeclare(),
    )
    .await
    {
        result?;
    }
    close_session(&session).await?;
    info!(
        published = report.published,
        malformed = report.malformed,
        interrupted = report.interrupted,
        seconds = start.elapsed().as_secs_f64(),
        "replay done"
    );
    Ok(report)
}
