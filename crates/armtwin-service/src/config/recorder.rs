//! `[recorder]` and each robot's `record`: the flight recorder's settings checked into
//! [`RecorderConfig`] (the section as written is `file`'s, beside the other sections).

use std::collections::HashMap;
use std::path::Path;

use super::ConfigError;
use super::file::{RecorderSection, RobotSection};
use armtwin_recorder::StoreSettings;

/// Most seconds `[recorder] history_s` may ask for: a day (the rings are allocated whole).
const MAX_HISTORY_S: usize = 86_400;

/// Smallest `[recorder] history_bytes`: a robot's ten closed minutes of seconds, and more.
const MIN_HISTORY_BYTES: u64 = 1 << 20;

/// The flight recorder's settings, checked.
#[derive(Debug, Clone, PartialEq)]
pub struct RecorderConfig {
    /// `[recorder] enabled`: whether a robot with no `record` of its own (nor one of
    /// `[robots.default]`) keeps a ring.
    pub enabled: bool,
    /// `record` of `[robots.default]` and of each `[robots."<id>"]` that sets it.
    pub robots: HashMap<String, bool>,
    /// Source time (s) an incident file holds before its trigger.
    pub pre_s: f64,
    /// Source time (s) it holds after.
    pub post_s: f64,
    /// A stamp gap longer than this (s) is an incident.
    pub gap_s: f64,
    /// The most a robot's rings hold (bytes).
    pub robot_bytes: usize,
    /// The most every robot's rings hold together (bytes).
    pub fleet_bytes: usize,
    /// The size of the log that holds the robots' closed minutes of history seconds (bytes).
    pub history_bytes: u64,
    /// Whether incident files draw the robot: its URDF on `/robot_description` and its link
    /// frames on `/tf` at each joint sample.
    pub draw_robot: bool,
    /// Where files go and how many are kept (`dir` resolved against the file's directory).
    pub store: StoreSettings,
}

impl RecorderConfig {
    /// Whether robot `id` keeps a ring: its own `record`, else `[robots.default]`'s, else
    /// `[recorder] enabled`.
    #[must_use]
    pub fn records(&self, id: &str) -> bool {
        self.robots
            .get(id)
            .or_else(|| self.robots.get("default"))
            .copied()
            .unwrap_or(self.enabled)
    }

    /// The span of source time (s) a ring keeps: what an incident file holds, and a second
    /// more, since the file is cut at the first sample past its `post_s` and must still find
    /// the first of its `pre_s`.
    #[must_use]
    pub fn span_s(&self) -> f64 {
        self.pre_s + self.post_s + 1.0
    }
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self::of(&RecorderSection::default(), HashMap::new(), Path::new(""))
    }
}

impl RecorderConfig {
    /// `section` as it reads, with the robots' `record` and `dir` taken from `base_dir`.
    fn of(section: &RecorderSection, robots: HashMap<String, bool>, base_dir: &Path) -> Self {
        Self {
            enabled: section.enabled,
            robots,
            pre_s: section.pre_s,
            post_s: section.post_s,
            gap_s: section.gap_s,
            robot_bytes: section.robot_bytes,
            fleet_bytes: section.fleet_bytes,
            history_bytes: section.history_bytes,
            draw_robot: section.draw_robot,
            store: StoreSettings {
                dir: base_dir.join(&section.dir),
                max_files: section.max_files,
                max_bytes: section.max_bytes,
                robot_max_files: section.robot_max_files,
                robot_max_bytes: section.robot_max_bytes,
            },
        }
    }
}

/// Checks `[recorder]` and the robots' `record`.
pub(super) fn load_recorder(
    section: &RecorderSection,
    robots: &HashMap<String, RobotSection>,
    (source_name, base_dir): (&str, &Path),
) -> Result<RecorderConfig, ConfigError> {
    let invalid = |field: &str, problem: String| ConfigError::Invalid {
        source_name: source_name.to_owned(),
        field: format!("recorder.{field}"),
        problem,
    };
    for (field, value) in [
        ("pre_s", section.pre_s),
        ("post_s", section.post_s),
        ("gap_s", section.gap_s),
    ] {
        if !(value.is_finite() && value >= 0.0) {
            return Err(invalid(field, format!("{value} is not a duration ≥ 0")));
        }
    }
    if section.pre_s + section.post_s > 3600.0 {
        return Err(invalid(
            "pre_s",
            "pre_s + post_s is over an hour: the rings are for seconds".to_owned(),
        ));
    }
    if section.history_s > MAX_HISTORY_S {
        return Err(invalid(
            "history_s",
            format!(
                "{} is over a day ({MAX_HISTORY_S} s): each minute costs every robot {} bytes",
                section.history_s,
                size_of::<armtwin_core::metrics::SecondTotals>()
            ),
        ));
    }
    if section.history_bytes < MIN_HISTORY_BYTES {
        return Err(invalid(
            "history_bytes",
            format!(
                "{} is under {MIN_HISTORY_BYTES}: the log must hold a robot's closed minutes",
                section.history_bytes
            ),
        ));
    }
    for (field, files) in [
        ("max_files", section.max_files),
        ("robot_max_files", section.robot_max_files),
    ] {
        if files == 0 {
            return Err(invalid(
                field,
                "0 would remove every file it writes".to_owned(),
            ));
        }
    }
    let records = robots
        .iter()
        .filter_map(|(id, robot)| Some((id.clone(), robot.record?)))
        .collect();
    Ok(RecorderConfig::of(section, records, base_dir))
}
