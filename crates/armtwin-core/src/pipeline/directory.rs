//! Which robots may be tracked, with which settings: the robot id resolved once per input.
//!
//! A [`RobotDirectory`] gives every robot a [`Robot`] handle (id, settings and a dense
//! [`RobotIndex`]) the first time it is asked for it: configured robots at construction, robots
//! under the default settings when first seen, as long as the directory holds fewer than its
//! limit. An entry never changes once made, so a caller may resolve and decode against it
//! without holding the twins' state (the service resolves under a read lock of its own, decodes,
//! and only then locks the pipeline). A robot admitted under the default may be forgotten (a
//! service retires robots that stopped sending): its index is then free for the next robot
//! admitted, so a fleet that churns keeps its per-robot vectors as long as its largest size.

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use super::RobotSettings;

/// A robot's place in its [`RobotDirectory`]: dense from 0 and stable for as long as the robot is
/// in the directory, so the pipeline and sinks keep per-robot state in a `Vec` and never hash the
/// id again. The index of a forgotten robot is given to the next robot admitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RobotIndex(usize);

impl RobotIndex {
    /// The index, for a `Vec` of per-robot state.
    #[must_use]
    pub fn get(self) -> usize {
        self.0
    }
}

/// A robot that may be tracked: its index, id and settings (shared, immutable), and the joint
/// count its twin computes with.
#[derive(Debug, Clone)]
pub struct Robot {
    index: RobotIndex,
    id: Arc<str>,
    settings: Arc<RobotSettings>,
    /// Its settings' model's joint count until its twin takes a model of another count (its
    /// own description): what its inputs are decoded against, read without its twin's lock.
    joint_count: Arc<AtomicUsize>,
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

    /// The joint count its twin computes with: its inputs are decoded against it.
    #[must_use]
    pub fn joint_count(&self) -> usize {
        self.joint_count.load(Ordering::Relaxed)
    }

    /// Its inputs are decoded against `joint_count` joints: its twin took a model
    /// of that many, or will (a robot back after a retirement, with a model of its own).
    pub fn set_joint_count(&self, joint_count: usize) {
        self.joint_count.store(joint_count, Ordering::Relaxed);
    }
}

/// Why a robot may not be tracked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Untracked {
    /// It is neither configured nor covered by a default.
    Unknown,
    /// The directory holds as many robots as it may ([`RobotDirectory::limit_to`]).
    Full {
        /// The limit.
        max_robots: usize,
    },
    /// The robot's group holds as many robots as it may ([`RobotDirectory::with_groups`]).
    GroupFull {
        /// The group's limit.
        max_robots: usize,
        /// The group's prefix is the robot id's first `prefix_len` bytes (less its last `/`).
        prefix_len: usize,
    },
}

/// Robots whose ids start with one prefix (`site-a/`), admitted up to a limit of their own: one
/// gateway granted a prefix cannot fill the fleet's `max_robots` with made-up ids.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RobotGroup {
    /// Every id that starts with it belongs to the group (the longest such prefix's group), and
    /// the prefix without its last `/` too (`site-a/**` covers `site-a`).
    pub prefix: String,
    /// Robots of the group admitted under the default settings at most.
    pub max_robots: usize,
}

impl RobotGroup {
    /// Whether robot `id` belongs to the group.
    #[must_use]
    pub fn contains(&self, id: &str) -> bool {
        id.starts_with(self.prefix.as_str()) || self.prefix.strip_suffix('/') == Some(id)
    }
}

/// Robots with settings, by id: the configured ones for good, robots under the default settings
/// from their admission until they are forgotten.
#[derive(Debug)]
pub struct RobotDirectory {
    default_settings: Option<Arc<RobotSettings>>,
    index_of: HashMap<Arc<str>, RobotIndex>,
    /// By index; `None` where a forgotten robot was.
    robots: Vec<Option<Robot>>,
    /// Indices of forgotten robots, reused first.
    free: Vec<RobotIndex>,
    /// The configured robots are the first `configured` indices, never forgotten.
    configured: usize,
    /// Most robots held; configured robots always fit.
    max_robots: usize,
    /// Groups by prefix, each with the robots of it held now (configured ones not counted).
    groups: Vec<(RobotGroup, usize)>,
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
            free: Vec::new(),
            configured: configured.len(),
            max_robots: usize::MAX,
            groups: Vec::new(),
        };
        for (id, settings) in configured {
            directory.insert(&id, Arc::new(settings));
        }
        directory
    }

    /// Admits robots under the default settings only while fewer than `max_robots` robots are
    /// held (configured ones included, which always fit).
    #[must_use]
    pub fn limit_to(mut self, max_robots: usize) -> Self {
        self.max_robots = max_robots;
        self
    }

    /// Admits robots under the default settings of each group only while fewer than its
    /// `max_robots` of them are held.
    #[must_use]
    pub fn with_groups(mut self, groups: Vec<RobotGroup>) -> Self {
        self.groups = groups.into_iter().map(|group| (group, 0)).collect();
        self
    }

    /// The group robot `id` belongs to (the longest prefix of it), by position.
    fn group_of(&self, id: &str) -> Option<usize> {
        self.groups
            .iter()
            .enumerate()
            .filter(|(_, (group, _))| group.contains(id))
            .max_by_key(|(_, (group, _))| group.prefix.len())
            .map(|(position, _)| position)
    }

    fn insert(&mut self, id: &str, settings: Arc<RobotSettings>) -> RobotIndex {
        let id: Arc<str> = Arc::from(id);
        let index = if let Some(index) = self.free.pop() {
            index
        } else {
            self.robots.push(None);
            RobotIndex(self.robots.len() - 1)
        };
        self.index_of.insert(Arc::clone(&id), index);
        let joint_count = Arc::new(AtomicUsize::new(settings.model.joint_count()));
        self.robots[index.0] = Some(Robot {
            index,
            id,
            settings,
            joint_count,
        });
        index
    }

    /// The robot `id`, if it is configured or was admitted under the default (one hash of the
    /// id).
    #[must_use]
    pub fn find(&self, id: &str) -> Option<&Robot> {
        let index = self.index_of.get(id)?;
        self.robots.get(index.0)?.as_ref()
    }

    /// The robot `id`, admitted under the default settings if it is not yet in the directory and
    /// the directory is not full. A refused id allocates nothing.
    pub fn admit(&mut self, id: &str) -> Result<&Robot, Untracked> {
        let index = if let Some(&index) = self.index_of.get(id) {
            index
        } else {
            self.admission_of(id)?;
            let settings = self.default_settings.clone().ok_or(Untracked::Unknown)?;
            let group = self.group_of(id);
            if let Some(group) = group {
                self.groups[group].1 += 1;
            }
            self.insert(id, settings)
        };
        self.robots
            .get(index.0)
            .and_then(Option::as_ref)
            .ok_or(Untracked::Unknown)
    }

    /// Whether a robot not in the directory would be admitted now, or why not; admits nothing
    /// (a caller checks under a read lock before taking a write lock to admit).
    pub fn admission(&self) -> Result<(), Untracked> {
        if self.default_settings.is_none() {
            Err(Untracked::Unknown)
        } else if self.is_full() {
            Err(Untracked::Full {
                max_robots: self.max_robots,
            })
        } else {
            Ok(())
        }
    }

    /// Whether robot `id`, not in the directory, would be admitted now, or why not: as
    /// [`admission`](Self::admission), and within its group's limit.
    pub fn admission_of(&self, id: &str) -> Result<(), Untracked> {
        self.admission()?;
        match self.group_of(id) {
            Some(group) if self.groups[group].1 >= self.groups[group].0.max_robots => {
                let (group, _) = &self.groups[group];
                Err(Untracked::GroupFull {
                    max_robots: group.max_robots,
                    // The id is the prefix itself, less its `/`, when it is shorter.
                    prefix_len: group.prefix.len().min(id.len()),
                })
            }
            _ => Ok(()),
        }
    }

    /// Whether no further robot may be admitted.
    fn is_full(&self) -> bool {
        self.index_of.len() >= self.max_robots
    }

    /// The most robots held.
    #[must_use]
    pub fn max_robots(&self) -> usize {
        self.max_robots
    }

    /// Robots held (configured and admitted).
    #[must_use]
    pub fn len(&self) -> usize {
        self.index_of.len()
    }

    /// Whether no robot is held.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.index_of.is_empty()
    }

    /// Whether `robot` is one of the configured robots (never forgotten).
    #[must_use]
    pub fn is_configured(&self, robot: &Robot) -> bool {
        robot.index.0 < self.configured
    }

    /// Forgets `robot` if it is this directory's entry for its id and was admitted under the
    /// default: its id no longer resolves and its index goes to the next robot admitted. A
    /// configured robot, or a handle of an entry already forgotten, is left alone (`false`).
    pub fn forget(&mut self, robot: &Robot) -> bool {
        let current = self.robots.get(robot.index.0).and_then(Option::as_ref);
        if self.is_configured(robot)
            || !current.is_some_and(|entry| Arc::ptr_eq(&entry.id, &robot.id))
        {
            return false;
        }
        self.index_of.remove(robot.id());
        self.robots[robot.index.0] = None;
        self.free.push(robot.index);
        if let Some(group) = self.group_of(robot.id()) {
            self.groups[group].1 = self.groups[group].1.saturating_sub(1);
        }
        // After a flood of ids has come and gone, give the table's memory back.
        if self.index_of.capacity() > 64 && self.index_of.len() * 4 < self.index_of.capacity() {
            self.index_of.shrink_to_fit();
        }
        true
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

#[cfg(test)]
mod tests {
    #![allow(
        clippy::expect_used,
        reason = "a test that fails an expectation fails the test"
    )]

    use super::*;
    use crate::model::RobotModel;
    use crate::pipeline::AlarmConfig;

    fn settings() -> RobotSettings {
        RobotSettings {
            model: Arc::new(RobotModel::nominal("ur10e").expect("catalog")),
            alarm: AlarmConfig::default(),
            sensors: Vec::new(),
            self_calibration: None,
            effort: None,
        }
    }

    fn directory(max_robots: usize) -> RobotDirectory {
        let configured = HashMap::from([
            ("cell/a".to_owned(), settings()),
            ("cell/b".to_owned(), settings()),
        ]);
        RobotDirectory::new(Some(settings()), configured).limit_to(max_robots)
    }

    #[test]
    fn a_full_directory_refuses_new_ids_and_keeps_admitting_known_ones() {
        let mut robots = directory(3);
        assert!(robots.admit("new/1").is_ok());
        assert_eq!(
            robots.admit("new/2").map(Robot::index),
            Err(Untracked::Full { max_robots: 3 })
        );
        assert!(robots.admit("new/1").is_ok(), "a robot held is found");
        assert!(
            robots.admit("cell/a").is_ok(),
            "configured robots always fit"
        );
        assert_eq!(robots.len(), 3);
        // Configured robots beyond the limit are held, and nothing else is admitted.
        let mut over = directory(1);
        assert_eq!(over.len(), 2);
        assert!(matches!(over.admit("new/1"), Err(Untracked::Full { .. })));
        let mut unknown = RobotDirectory::new(None, HashMap::new());
        assert_eq!(
            unknown.admit("x").map(Robot::index),
            Err(Untracked::Unknown)
        );
    }

    #[test]
    fn a_group_fills_its_own_share_and_leaves_the_fleet_its_room() {
        let groups = vec![
            RobotGroup {
                prefix: "site-a/".to_owned(),
                max_robots: 2,
            },
            RobotGroup {
                prefix: "site-a/cell-9/".to_owned(),
                max_robots: 1,
            },
        ];
        let mut robots = directory(10).with_groups(groups);
        let first = robots.admit("site-a/1").expect("room").clone();
        assert!(robots.admit("site-a/2").is_ok());
        assert_eq!(
            robots.admit("site-a/3").map(Robot::index),
            Err(Untracked::GroupFull {
                max_robots: 2,
                prefix_len: "site-a/".len()
            })
        );
        // The longest prefix's group, with its own share.
        assert!(robots.admit("site-a/cell-9/x").is_ok());
        assert!(matches!(
            robots.admit("site-a/cell-9/y"),
            Err(Untracked::GroupFull { max_robots: 1, .. })
        ));
        // Outside the groups, the fleet's room is left; a configured id always fits.
        assert!(robots.admit("r2").is_ok());
        assert!(robots.admit("cell/a").is_ok());
        // The prefix itself is the group's, as `site-a/**` covers `site-a`.
        assert!(matches!(
            robots.admission_of("site-a"),
            Err(Untracked::GroupFull { max_robots: 2, .. })
        ));
        // A forgotten robot gives its group's place back.
        assert!(robots.forget(&first));
        assert!(robots.admit("site-a/3").is_ok());
        assert!(robots.admission_of("site-a/4").is_err());
    }

    #[test]
    fn a_forgotten_robot_frees_its_index_for_the_next_one_and_configured_ones_stay() {
        let mut robots = directory(3);
        let first = robots.admit("new/1").expect("admitted").clone();
        assert!(!robots.forget(&robots.find("cell/a").expect("configured").clone()));
        assert!(robots.forget(&first));
        assert!(!robots.forget(&first), "forgotten once");
        assert!(robots.find("new/1").is_none());
        let second = robots.admit("new/2").expect("room again").clone();
        assert_eq!(second.index(), first.index(), "the index is reused");
        assert!(
            !robots.forget(&first),
            "a stale handle does not forget its index's new robot"
        );
        assert_eq!(robots.find("new/2").map(Robot::index), Some(second.index()));
        let again = robots.admit("new/1");
        assert!(matches!(again, Err(Untracked::Full { .. })), "full again");
    }

    #[test]
    fn forgetting_a_flood_of_ids_gives_the_table_back() {
        let mut robots = directory(100_000);
        let handles: Vec<Robot> = (0..10_000)
            .map(|i| robots.admit(&format!("flood/{i}")).expect("room").clone())
            .collect();
        let capacity = robots.index_of.capacity();
        for robot in &handles {
            assert!(robots.forget(robot));
        }
        assert_eq!(robots.len(), 2);
        assert!(
            robots.index_of.capacity() * 16 < capacity,
            "{} of {capacity}",
            robots.index_of.capacity()
        );
    }
}
