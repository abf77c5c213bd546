//! `/metrics`: the twin's state in Prometheus' text format, written with the official
//! `prometheus-client` from one read of the fleet per scrape (nothing is kept between scrapes,
//! so a robot's series always say what the twin holds at the scrape).

use prometheus_client::encoding::text::encode;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::{Registry, Unit};
use std::sync::Arc;
use std::sync::atomic::AtomicU64;

use armtwin_core::dynamics::monitor::EffortSummary;
use armtwin_core::metrics::{Metric, Stats, StatsSet};
use armtwin_core::sample::JointQuantity;
use armtwin_view::{FleetRow, ServiceTotals};

/// A series' labels: a few pairs, the robot's first.
type Labels = Vec<(&'static str, String)>;
type Gauges = Family<Labels, Gauge<f64, AtomicU64>>;
type Counters = Family<Labels, Counter<u64, AtomicU64>>;

/// One statistic's gauges of one metric (`position` in metres, `angle` in radians).
struct ErrorGauges {
    mae: Gauges,
    rmse: Gauges,
    max: Gauges,
}

impl ErrorGauges {
    fn register(registry: &mut Registry, quantity: &str, unit: &Unit, what: &str) -> Self {
        let gauges = Self {
            mae: Gauges::default(),
            rmse: Gauges::default(),
            max: Gauges::default(),
        };
        for (statistic, family, help) in [
            ("mae", &gauges.mae, "mean absolute"),
            ("rmse", &gauges.rmse, "root mean square"),
            ("max", &gauges.max, "largest"),
        ] {
            registry.register_with_unit(
                format!("{quantity}_error_{statistic}"),
                format!("Twin-vs-measured {what}, {help} (scope: cumulative since start or reset, or the sliding window)"),
                unit.clone(),
                family.clone(),
            );
        }
        gauges
    }

    fn set(&self, robot: &str, scope: &'static str, stats: &Stats) {
        let labels = vec![("robot", robot.to_owned()), ("scope", scope.to_owned())];
        self.mae.get_or_create(&labels).set(stats.mae);
        self.rmse.get_or_create(&labels).set(stats.rmse);
        self.max.get_or_create(&labels).set(stats.max);
    }
}

/// The per-robot families of one exposition.
struct RobotFamilies {
    position: ErrorGauges,
    rotation: ErrorGauges,
    pairs: Gauges,
    poses: Counters,
    paired: Counters,
    unpaired: Counters,
    rejected: Counters,
    alarm: Gauges,
    epoch: Gauges,
    joint_temperature: Gauges,
    joint_current: Gauges,
    joint_torque: Gauges,
    joint_model_torque: Gauges,
    joint_residual: Gauges,
    joint_observer: Gauges,
    joint_friction: Gauges,
    payload: Gauges,
    collision_active: Gauges,
    collisions: Counters,
    payload_mismatch: Gauges,
    last_sample_age: Gauges,
}

impl RobotFamilies {
    fn register(registry: &mut Registry) -> Self {
        let position =
            ErrorGauges::register(registry, "position", &Unit::Meters, "TCP position distance");
        let rotation = ErrorGauges::register(
            registry,
            "rotation",
            &Unit::Other("radians".to_owned()),
            "TCP rotation angle",
        );
        let families = Self {
            position,
            rotation,
            pairs: Gauges::default(),
            poses: Counters::default(),
            paired: Counters::default(),
            unpaired: Counters::default(),
            rejected: Counters::default(),
            alarm: Gauges::default(),
            epoch: Gauges::default(),
            joint_temperature: Gauges::default(),
            joint_current: Gauges::default(),
            joint_torque: Gauges::default(),
            joint_model_torque: Gauges::default(),
            joint_residual: Gauges::default(),
            joint_observer: Gauges::default(),
            joint_friction: Gauges::default(),
            payload: Gauges::default(),
            collision_active: Gauges::default(),
            collisions: Counters::default(),
            payload_mismatch: Gauges::default(),
            last_sample_age: Gauges::default(),
        };
        let gauges = [
            (
                "window_pairs",
                "Paired measurements in the robot's sliding window",
                &families.pairs,
            ),
            (
                "alarm_active",
                "1 while the robot's position or angle alarm is active",
                &families.alarm,
            ),
            (
                "metrics_epoch",
                "Times the robot's model was replaced (an applied self-calibration)",
                &families.epoch,
            ),
            (
                "joint_temperature_celsius",
                "The robot's joint temperature as its source last reported it",
                &families.joint_temperature,
            ),
            (
                "joint_current_amperes",
                "The robot's joint motor current as its source last reported it",
                &families.joint_current,
            ),
            (
                "joint_torque_newton_metres",
                "The robot's measured joint torque as its source last reported it",
                &families.joint_torque,
            ),
        ];
        for (name, help, family) in gauges {
            registry.register(name, help, family.clone());
        }
        families.register_effort(registry);
        let counters = [
            (
                "poses",
                "Twin poses the robot's joint samples produced",
                &families.poses,
            ),
            (
                "paired",
                "Measured poses paired with the twin (current metrics epoch)",
                &families.paired,
            ),
            (
                "unpaired",
                "Measured poses that could not be paired (current metrics epoch)",
                &families.unpaired,
            ),
            (
                "rejected",
                "Inputs of the robot rejected, by cause",
                &families.rejected,
            ),
            (
                "collisions",
                "Collision alarms raised on the robot",
                &families.collisions,
            ),
        ];
        for (name, help, family) in counters {
            registry.register(name, help, family.clone());
        }
        families
    }

    fn add(&self, row: &FleetRow) {
        let robot = &*row.id;
        let robot_labels = || vec![("robot", robot.to_owned())];
        let scopes: [(&'static str, &StatsSet); 2] = [
            ("cumulative", &row.metrics.cumulative),
            ("window", &row.metrics.window),
        ];
        for (scope, set) in scopes {
            self.position.set(robot, scope, set.of(Metric::Position));
            self.rotation.set(robot, scope, set.of(Metric::Angle));
        }
        self.pairs
            .get_or_create(&robot_labels())
            .set(row.metrics.window.n as f64);
        self.poses
            .get_or_create(&robot_labels())
            .inc_by(row.counts.poses);
        self.paired
            .get_or_create(&robot_labels())
            .inc_by(row.metrics.paired);
        self.unpaired
            .get_or_create(&robot_labels())
            .inc_by(row.metrics.unpaired);
        for &(cause, count) in &row.counts.rejected_by_cause {
            let labels = vec![
                ("robot", robot.to_owned()),
                ("cause", cause.as_str().to_owned()),
            ];
            self.rejected.get_or_create(&labels).inc_by(count);
        }
        for (metric, active) in row.alarms_active.by_metric() {
            let labels = vec![
                ("robot", robot.to_owned()),
                ("metric", metric.as_str().to_owned()),
            ];
            self.alarm
                .get_or_create(&labels)
                .set(f64::from(u8::from(active)));
        }
        self.epoch
            .get_or_create(&robot_labels())
            .set(row.metrics.epoch as f64);
        self.last_sample_age
            .get_or_create(&robot_labels())
            .set(row.last_sample_age_s);
        if let Some(effort) = &row.metrics.effort {
            self.add_effort(robot, effort);
        }
        if let Some(state) = &row.joint_state {
            let per_joint = [
                (JointQuantity::Temperature, &self.joint_temperature),
                (JointQuantity::Current, &self.joint_current),
                (JointQuantity::Torque, &self.joint_torque),
            ];
            for (quantity, family) in per_joint {
                for (joint, value) in state.get(quantity).unwrap_or(&[]).iter().enumerate() {
                    let labels = vec![
                        ("robot", robot.to_owned()),
                        ("joint", (joint + 1).to_string()),
                    ];
                    family.get_or_create(&labels).set(*value);
                }
            }
        }
    }
}

impl RobotFamilies {
    /// Registers the effort gauges (robots with `effort = true`), and the age of each robot's
    /// last sample.
    fn register_effort(&self, registry: &mut Registry) {
        registry.register_with_unit(
            "robot_last_sample_age",
            "Time since the robot's last sample (joints or measured pose) arrived, at the scrape",
            Unit::Seconds,
            self.last_sample_age.clone(),
        );
        let gauges = [
            (
                "joint_model_torque_newton_metres",
                "The effort model's joint torque for the robot's latest sample (effort = true)",
                &self.joint_model_torque,
            ),
            (
                "joint_torque_residual_rms_newton_metres",
                "RMS of measured minus model minus friction torque, by scope (cumulative, window)",
                &self.joint_residual,
            ),
            (
                "joint_observer_newton_metres",
                "The momentum observer's estimate of the torque the drives spend beyond the model",
                &self.joint_observer,
            ),
            (
                "joint_friction_newton_metres",
                "The joint's fitted Coulomb friction, and its drift from the first fit at the same temperature",
                &self.joint_friction,
            ),
            (
                "payload_kilograms",
                "The payload mass the effort model uses (in_use) and the one identified at rest (estimated)",
                &self.payload,
            ),
            (
                "collision_active",
                "1 while a joint's collision alarm is on",
                &self.collision_active,
            ),
            (
                "payload_mismatch_active",
                "1 while the payload identified at rest is further from the one in use than the tolerance",
                &self.payload_mismatch,
            ),
        ];
        for (name, help, family) in gauges {
            registry.register(name, help, family.clone());
        }
    }

    /// A watched robot's effort gauges.
    fn add_effort(&self, robot: &str, effort: &EffortSummary) {
        let joint_labels = |joint: usize, extra: Option<(&'static str, &'static str)>| {
            let mut labels = vec![
                ("robot", robot.to_owned()),
                ("joint", (joint + 1).to_string()),
            ];
            if let Some((name, value)) = extra {
                labels.push((name, value.to_owned()));
            }
            labels
        };
        if let Some(latest) = &effort.latest {
            for (joint, value) in latest.model_nm.iter().enumerate() {
                self.joint_model_torque
                    .get_or_create(&joint_labels(joint, None))
                    .set(*value);
            }
            for (joint, value) in latest.observer_nm.iter().flatten().enumerate() {
                self.joint_observer
                    .get_or_create(&joint_labels(joint, None))
                    .set(*value);
            }
        }
        for (scope, stats) in [
            ("cumulative", &effort.cumulative),
            ("window", &effort.window),
        ] {
            if stats.n == 0 {
                continue;
            }
            for (joint, value) in stats.rms_nm.iter().enumerate() {
                self.joint_residual
                    .get_or_create(&joint_labels(joint, Some(("scope", scope))))
                    .set(*value);
            }
        }
        for (joint, friction) in effort.friction.iter().enumerate() {
            let Some(friction) = friction else {
                continue;
            };
            self.joint_friction
                .get_or_create(&joint_labels(joint, Some(("kind", "coulomb"))))
                .set(friction.coulomb_nm);
            if let Some(drift) = friction.drift_nm {
                self.joint_friction
                    .get_or_create(&joint_labels(joint, Some(("kind", "drift"))))
                    .set(drift);
            }
        }
        let payload_labels =
            |kind: &'static str| vec![("robot", robot.to_owned()), ("kind", kind.to_owned())];
        self.payload
            .get_or_create(&payload_labels("in_use"))
            .set(effort.payload.in_use.0.mass_kg);
        if let Some(estimate) = &effort.payload.estimate {
            self.payload
                .get_or_create(&payload_labels("estimated"))
                .set(estimate.mass_kg);
        }
        for (joint, active) in effort.collision.iter().enumerate() {
            self.collision_active
                .get_or_create(&joint_labels(joint, None))
                .set(f64::from(u8::from(*active)));
        }
        self.collisions
            .get_or_create(&vec![("robot", robot.to_owned())])
            .inc_by(effort.collisions);
        self.payload_mismatch
            .get_or_create(&vec![("robot", robot.to_owned())])
            .set(f64::from(u8::from(effort.payload_mismatch)));
    }
}

/// The service's counters: name, help and value.
fn total_counters(totals: &ServiceTotals) -> Vec<(&'static str, &'static str, u64)> {
    vec![
        (
            "inputs",
            "Inputs (samples and queries) processed",
            totals.inputs,
        ),
        (
            "published_poses",
            "Twin poses published, all robots",
            totals.poses,
        ),
        (
            "publish_errors",
            "Outputs Zenoh refused to send",
            totals.publish_errors,
        ),
        (
            "robots_refused",
            "Samples of new robots refused because the fleet was full (service.max_robots)",
            totals.robots_refused,
        ),
        (
            "robots_retired",
            "Robots retired after service.forget_after_s without input",
            totals.robots_retired,
        ),
        (
            "snapshot_failures",
            "Snapshot writes that failed (tried again next period)",
            totals.snapshot_failures,
        ),
        (
            "descriptions_refused",
            "Robots' descriptions refused (unreadable, too large or too frequent, of another \
             joint count, or disagreeing with the robot's own model)",
            totals.descriptions_refused,
        ),
        (
            "recorder_files",
            "Incident files the flight recorder wrote",
            totals.recorder.files,
        ),
        (
            "recorder_written_bytes",
            "Bytes of the incident files written",
            totals.recorder.bytes,
        ),
        (
            "recorder_failures",
            "Incident files not written (a full disk, a full queue)",
            totals.recorder.failures,
        ),
        (
            "history_log_dropped",
            "Minutes of the histories' seconds not kept, the disk behind (their minutes are)",
            totals.history_log.dropped,
        ),
        (
            "history_log_write_failures",
            "Writes to the history log's file that failed (it went on in memory after the first)",
            totals.history_log.write_failures,
        ),
    ]
}

/// Registers the service's totals in `registry`.
fn register_totals(registry: &mut Registry, totals: &ServiceTotals) {
    for (name, help, value) in total_counters(totals) {
        let counter: Counter<u64, AtomicU64> = Counter::default();
        counter.inc_by(value);
        registry.register(name, help, counter);
    }
    let logs = [
        (
            "recorder_ring",
            "Bytes the flight recorder's log of every robot's recent streams holds (on disk; in memory when the disk refused it)",
            totals.recorder.ring_bytes,
        ),
        (
            "history_log",
            "Bytes the log of the histories' closed minutes of seconds holds ([recorder] history_bytes at most)",
            totals.history_log.bytes,
        ),
    ];
    for (name, help, bytes) in logs {
        let gauge: Gauge<f64, AtomicU64> = Gauge::default();
        gauge.set(bytes as f64);
        registry.register_with_unit(name, help, Unit::Bytes, gauge);
    }
    let tracked: Gauge<f64, AtomicU64> = Gauge::default();
    tracked.set(totals.robots as f64);
    registry.register("robots_tracked", "Robots the twin tracks", tracked);
    let max_robots: Gauge<f64, AtomicU64> = Gauge::default();
    max_robots.set(totals.max_robots as f64);
    registry.register(
        "robots_max",
        "The most robots the twin tracks (service.max_robots)",
        max_robots,
    );
    if let Some(age_s) = totals.snapshot_age_s {
        let age: Gauge<f64, AtomicU64> = Gauge::default();
        age.set(age_s);
        registry.register_with_unit(
            "snapshot_age",
            "Time since the twins' snapshot was last written",
            Unit::Seconds,
            age,
        );
    }
}

/// Registers `armtwin_gateway_streaming`: per robot whose gateway holds (or held) a token, 1
/// while it streams.
fn register_gateways(registry: &mut Registry, gateways: &[(Arc<str>, bool)]) {
    let streaming = Gauges::default();
    for (robot, streams) in gateways {
        streaming
            .get_or_create(&vec![("robot", robot.to_string())])
            .set(f64::from(u8::from(*streams)));
    }
    registry.register(
        "gateway_streaming",
        "1 while the robot's gateway streams it from its controller, 0 while it connects, waits \
         or is gone (liveliness tokens <prefix>/gateway/streaming|waiting/<robot>)",
        streaming,
    );
}

/// Registers `armtwin_robot_expected`: 1 per robot the configuration names, from the service's
/// start, so that a robot which never speaks after a restart has a series an alert can miss its
/// sample age beside.
fn register_expected(registry: &mut Registry, expected: &[Arc<str>]) {
    let family = Gauges::default();
    for robot in expected {
        family
            .get_or_create(&vec![("robot", robot.to_string())])
            .set(1.0);
    }
    registry.register(
        "robot_expected",
        "1 for each robot the configuration names in a robots.<id> table: expected to stream from \
         the start, whether it has spoken since or not",
        family,
    );
}

/// The exposition of the fleet's rows, its gateways, the robots it expects and the service's
/// totals (`OpenMetrics` text, which Prometheus reads; it ends with `# EOF`).
pub(crate) fn render(
    totals: &ServiceTotals,
    rows: &[FleetRow],
    gateways: &[(Arc<str>, bool)],
    expected: &[Arc<str>],
) -> String {
    let mut registry = Registry::with_prefix("armtwin");
    let families = RobotFamilies::register(&mut registry);
    for row in rows {
        families.add(row);
    }
    register_gateways(&mut registry, gateways);
    register_expected(&mut registry, expected);
    register_totals(&mut registry, totals);
    let mut text =
        String::with_capacity(256 + rows.len() * 2048 + (gateways.len() + expected.len()) * 64);
    // Writing into a String cannot fail.
    let _ = encode(&mut text, &registry);
    text
}
