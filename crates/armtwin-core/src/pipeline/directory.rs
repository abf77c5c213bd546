//! Which robots may be tracked, with which settings: the robot id resolved once per input.
//!
//! A [`RobotDirectory`] gives every robot a [`Robot`] handle (id, settings and a dense
//! [`RobotIndex`]) the first time it is asked for it: configured robots at construction, robots
//! under the default settings when first seen. An entry never changes once made, so a caller
//! may resolve and decode against it without holding the twins' state (the service resolves under
//! a read lock of its own, decodes, and only then locks the pipeline).

use std::collections::HashMap;
use std::sync::Arc;

use super::RobotSettings;

/// A robot's place in its [`RobotDirectory`]: dense from 0 and stable for the directory's life,
/// so the pipeline and sinks keep per-robot state in a `Vec` and never hash the id again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RobotIndex(usize);

impl RobotIndex {
    /// The index, for a `Vec` of per-robot state.
    #[must_use]
    pub fn get(self) -> usize {
        self.0
    }
}

/// A robot that may be tracked: its index, id and settings (shared, immutable).
#[derive(Debug, Clone)]
pub struct Robot {
    index: RobotIndex,
    id: Arc<str>,
    settings: Arc<RobotSettings>,
}

impl Robot {
    /// Its index in the directory.
    #[must_use]
    pub fn index(&self) -> RobotIndex {
        self.index
    }

    /// Its id.
    #[must_use]
    pub fn id(&self) -> &str {
        &self.id
    }

    /// Its id, shared.
    #[must_use]
    pub fn shared_id(&self) -> &Arc<str> {
        &self.id
    }

    /// Its settings (its own, or the default).
    #[must_use]
    pub fn settings(&self) -> &RobotSettings {
        &self.settings
    }
}

/// Why a robot may not be tracked: it is neither configured nor covered by a default.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnknownRobot;

/// Robots with settings, by id; grows only (by robots under the default settings).
#[derive(Debug)]
pub struct RobotDirectory {
    default_settings: Option<Arc<RobotSettings>>,
    index_of: HashMap<Arc<str>, RobotIndex>,
    robots: Vec<Robot>,
}

impl RobotDirectory {
    /// The robots `configured` with their own settings (indexed in id order), and
    /// `default_settings` for robots not listed (`None`: robots not listed may not be tracked).
    #[must_use]
    pub fn new(
        default_settings: Option<RobotSettings>,
        configured: HashMap<String, RobotSettings>,
    ) -> Self {
        let mut configured: Vec<(String, RobotSettings)> = configured.into_iter().collect();
        configured.sort_by(|a, b| a.0.cmp(&b.0));
        let mut directory = Self {
            default_settings: default_settings.map(Arc::new),
            index_of: HashMap::with_capacity(configured.len()),
            robots: Vec::with_capacity(configured.len()),
        };
        for (id, settings) in configured {
            directory.insert(&id, Arc::new(settings));
        }
        directory
    }

    fn insert(&mut self, id: &str, settings: Arc<RobotSettings>) -> RobotIndex {
        let index = RobotIndex(self.robots.len());
        let id: Arc<str> = Arc::from(id);
        self.index_of.insert(Arc::clone(&id), index);
        self.robots.push(Robot {
            index,
            id,
            settings,
        });
        index
    }

    /// The robot `id`, if it is configured or was admitted under the default (one hash of the
    /// id).
    #[must_use]
    pub fn find(&self, id: &str) -> Option<&Robot> {
        let index = self.index_of.get(id)?;
        self.robots.get(index.0)
    }

    /// The robot `id`, admitted under the default settings if it is not yet in the directory.
    pub fn admit(&mut self, id: &str) -> Result<&Robot, UnknownRobot> {
        let index = if let Some(&index) = self.index_of.get(id) {
            index
        } else {
            let settings = self.default_settings.clone().ok_or(UnknownRobot)?;
            self.insert(id, settings)
        };
        self.robots.get(index.0).ok_or(UnknownRobot)
    }

    /// Whether robots that are not listed are admitted (under the default settings).
    #[must_use]
    pub fn admits_unlisted(&self) -> bool {
        self.default_settings.is_some()
    }

    /// The settings robot `id` has or would get, without admitting it.
    #[must_use]
    pub fn settings_for(&self, id: &str) -> Option<&RobotSettings> {
        self.find(id)
            .map(|robot| &robot.settings)
            .or(self.default_settings.as_ref())
            .map(Arc::as_ref)
    }
}
