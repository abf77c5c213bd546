//! armtwin's JSON output messages: the twin's pose, deviation, event, metrics and state, and the
//! live self-calibration's estimate, each a plain `Serialize` struct built from the core's
//! results; the per-sample ones also write themselves with the fixed-layout writer.

use armtwin_core::identify::{Identification, PoseErrors};
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::{Deviation, METRIC_NAMES, Stats, StatsSet};
use armtwin_core::pipeline::{Alarms, Event, EventDetail, MetricsReadout, RobotState};
use armtwin_core::sample::JointState;
use armtwin_core::self_calibration::{CalibrationBatch, Estimate, FitError};
use serde::Serialize;
use serde_json::{Value, json};

use super::encode::FlatObject;
use crate::PoseFields;

/// Room for a pose or deviation message without growing, with every number at full precision
/// (17 digits and an exponent) and a long robot id.
const POSE_JSON_CAPACITY: usize = 512;

/// Room for a twin pose with its deviation, as [`POSE_JSON_CAPACITY`].
const PAIRED_JSON_CAPACITY: usize = 768;

/// Room for a metrics message (about 1.6 kB with full-precision statistics) without growing.
const METRICS_JSON_CAPACITY: usize = 2048;

/// A twin (or measured) pose: `{robot, t, seq, frame, x, y, z, roll, pitch, yaw, qx, qy, qz, qw}`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PoseMessage {
    /// Robot id.
    pub robot: String,
    /// Source time (s).
    pub t: f64,
    /// The twin's pose sequence number.
    pub seq: u64,
    /// The frame the pose is expressed in (`base`, `base_link`).
    pub frame: &'static str,
    /// Position (m), roll/pitch/yaw (rad) and quaternion (`qw ≥ 0`).
    #[serde(flatten)]
    pub pose: PoseFields,
}

impl PoseMessage {
    /// The message of `readout`, expressed in `frame` ([`armtwin_core::kinematics::OutputFrame::as_str`]).
    #[must_use]
    pub fn new(
        robot: impl Into<String>,
        t: f64,
        seq: u64,
        frame: &'static str,
        readout: &PoseReadout,
    ) -> Self {
        Self {
            robot: robot.into(),
            t,
            seq,
            frame,
            pose: PoseFields::from(readout),
        }
    }

    /// The message's JSON: the bytes [`to_json_bytes`](super::to_json_bytes) writes for it, written directly (this is
    /// the message the service sends for every joint sample).
    #[must_use]
    pub fn to_json_bytes(&self) -> Vec<u8> {
        pose_json_bytes(&self.robot, self.t, self.seq, self.frame, &self.pose)
    }
}

/// The JSON of a [`PoseMessage`], written without making one: the service writes one per joint
/// sample, and a message would copy the robot id first.
#[must_use]
pub fn pose_json_bytes(robot: &str, t: f64, seq: u64, frame: &str, pose: &PoseFields) -> Vec<u8> {
    pose_object(POSE_JSON_CAPACITY, robot, (t, seq), frame, pose).finish()
}

/// A twin pose's fields in an object of `capacity` bytes, left open for more.
fn pose_object(
    capacity: usize,
    robot: &str,
    (t, seq): (f64, u64),
    frame: &str,
    pose: &PoseFields,
) -> FlatObject {
    let mut object = FlatObject::with_capacity(capacity);
    object.string("robot", robot);
    object.number("t", t);
    object.unsigned("seq", seq);
    object.string("frame", frame);
    for (name, value) in PoseFields::NAMES.into_iter().zip(pose.values()) {
        object.number(name, value);
    }
    object
}

/// The JSON of a twin pose (the fields of [`pose_json_bytes`]) followed, when a measured pose
/// was paired at its stamp, by that deviation's fields (those of [`deviation_json_bytes`] but
/// `robot` and `t`): `twin/paired/<robot>`'s message. One flat object, as the binary form is one
/// tuple: the names of the two parts never collide.
#[must_use]
pub fn paired_json_bytes(
    robot: &str,
    t: f64,
    seq: u64,
    frame: &str,
    pose: &PoseFields,
    deviation: Option<&Deviation>,
) -> Vec<u8> {
    let mut object = pose_object(PAIRED_JSON_CAPACITY, robot, (t, seq), frame, pose);
    if let Some(deviation) = deviation {
        deviation_fields(&mut object, deviation);
    }
    object.finish()
}

/// Twin minus measured for one paired sample (metres, radians):
/// `{robot, t, dx, dy, dz, position, quat_distance, angle, droll, dpitch, dyaw}`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviationMessage {
    /// Robot id.
    pub robot: String,
    /// Source time (s) of the pair.
    pub t: f64,
    /// `x_twin − x_measured` (m).
    pub dx: f64,
    /// `y_twin − y_measured` (m).
    pub dy: f64,
    /// `z_twin − z_measured` (m).
    pub dz: f64,
    /// Distance between the positions (m).
    pub position: f64,
    /// Quaternion distance `1 − |⟨a, b⟩|`, in [0, 1].
    pub quat_distance: f64,
    /// Rotation angle between the orientations (rad), in [0, π].
    pub angle: f64,
    /// Roll difference (rad), wrapped to (−π, π].
    pub droll: f64,
    /// Pitch difference (rad), wrapped to (−π, π].
    pub dpitch: f64,
    /// Yaw difference (rad), wrapped to (−π, π].
    pub dyaw: f64,
}

impl DeviationMessage {
    /// The message of `deviation`, observed at `t` (s).
    #[must_use]
    pub fn new(robot: impl Into<String>, t: f64, deviation: &Deviation) -> Self {
        Self {
            robot: robot.into(),
            t,
            dx: deviation.dx_m,
            dy: deviation.dy_m,
            dz: deviation.dz_m,
            position: deviation.position_m,
            quat_distance: deviation.quat_distance,
            angle: deviation.angle_rad,
            droll: deviation.droll_rad,
            dpitch: deviation.dpitch_rad,
            dyaw: deviation.dyaw_rad,
        }
    }

    /// The message's JSON: the bytes [`to_json_bytes`](super::to_json_bytes) writes for it, written directly (this is
    /// the message the service sends for every paired measured pose).
    #[must_use]
    pub fn to_json_bytes(&self) -> Vec<u8> {
        let deviation = Deviation {
            dx_m: self.dx,
            dy_m: self.dy,
            dz_m: self.dz,
            position_m: self.position,
            quat_distance: self.quat_distance,
            angle_rad: self.angle,
            droll_rad: self.droll,
            dpitch_rad: self.dpitch,
            dyaw_rad: self.dyaw,
        };
        deviation_json_bytes(&self.robot, self.t, &deviation)
    }
}

/// The JSON of a [`DeviationMessage`], written without making one: the service writes one per
/// paired measured pose, and a message would copy the robot id first.
#[must_use]
pub fn deviation_json_bytes(robot: &str, t: f64, deviation: &Deviation) -> Vec<u8> {
    let mut object = FlatObject::with_capacity(POSE_JSON_CAPACITY);
    object.string("robot", robot);
    object.number("t", t);
    deviation_fields(&mut object, deviation);
    object.finish()
}

/// The deviation's own fields, `dx` … `dyaw`.
fn deviation_fields(object: &mut FlatObject, deviation: &Deviation) {
    object.number("dx", deviation.dx_m);
    object.number("dy", deviation.dy_m);
    object.number("dz", deviation.dz_m);
    object.number("position", deviation.position_m);
    object.number("quat_distance", deviation.quat_distance);
    object.number("angle", deviation.angle_rad);
    object.number("droll", deviation.droll_rad);
    object.number("dpitch", deviation.dpitch_rad);
    object.number("dyaw", deviation.dyaw_rad);
}

/// Something a dashboard should hear about: `{robot, t, kind, reason, key?, detail?}`, `kind`
/// one of `rejected`, `alarm`, `recovered`, `gap`, `unpaired`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EventMessage {
    /// Robot id.
    pub robot: String,
    /// Source time (s) of the sample concerned.
    pub t: f64,
    /// [`armtwin_core::pipeline::EventKind::as_str`].
    pub kind: &'static str,
    /// A sentence for people.
    pub reason: String,
    /// The key the input arrived on, if an input is concerned (omitted when `None`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub key: Option<String>,
    /// Details for machines (omitted when `null`): `rejected` → `{cause}`; `alarm` and
    /// `recovered` → `{metric, value, threshold}` (`collision` adds `joint`, `payload`
    /// `mass_std_kg` and `configured_kg`); `gap` → `{gap_s}` or `{expected, got}`;
    /// `unpaired` → `{cause, measured_s}`.
    #[serde(skip_serializing_if = "Value::is_null")]
    pub detail: Value,
    /// Events of this robot the rate limit kept back since its previous published event (counted,
    /// not published; omitted when 0).
    #[serde(skip_serializing_if = "is_zero")]
    pub suppressed: u64,
}

#[allow(
    clippy::trivially_copy_pass_by_ref,
    reason = "serde's skip_serializing_if passes a reference"
)]
fn is_zero(n: &u64) -> bool {
    *n == 0
}

impl EventMessage {
    /// The message of a pipeline event (its `reason` the event's sentence, written here).
    #[must_use]
    pub fn new(event: &Event<'_>) -> Self {
        let detail = match event.detail {
            EventDetail::Rejected { cause } => json!({ "cause": cause.as_str() }),
            EventDetail::Alarm {
                metric,
                value,
                threshold,
            } => json!({ "metric": metric, "value": value, "threshold": threshold }),
            EventDetail::StampGap { gap_s } => json!({ "gap_s": gap_s }),
            EventDetail::Restart { from_s, to_s } => json!({ "from_s": from_s, "to_s": to_s }),
            EventDetail::SeqGap { expected, got } => json!({ "expected": expected, "got": got }),
            EventDetail::SeqRestart { from_seq, to_seq } => {
                json!({ "from_seq": from_seq, "to_seq": to_seq })
            }
            EventDetail::Unpaired { cause, measured_s } => {
                json!({ "cause": cause, "measured_s": measured_s })
            }
            EventDetail::Epoch { epoch } => json!({ "epoch": epoch }),
            EventDetail::Collision {
                joint,
                value_nm,
                threshold_nm,
            } => json!({
                "metric": "collision", "joint": joint, "value": value_nm, "threshold": threshold_nm
            }),
            EventDetail::Payload {
                estimated_kg,
                std_kg,
                modelled_kg,
                tolerance_kg,
            } => json!({
                "metric": "payload", "value": estimated_kg, "threshold": tolerance_kg,
                "mass_std_kg": std_kg, "configured_kg": modelled_kg
            }),
        };
        Self {
            robot: event.robot.to_owned(),
            t: event.stamp_s,
            kind: event.kind.as_str(),
            reason: event.to_string(),
            key: event.key.map(str::to_owned),
            detail,
            suppressed: 0,
        }
    }
}

/// Error statistics of one metric: `{mae, rmse, max}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StatsJson {
    /// Mean absolute error.
    pub mae: f64,
    /// Root mean square error.
    pub rmse: f64,
    /// Largest magnitude.
    pub max: f64,
}

impl From<&Stats> for StatsJson {
    fn from(stats: &Stats) -> Self {
        Self {
            mae: stats.mae,
            rmse: stats.rmse,
            max: stats.max,
        }
    }
}

/// Statistics of every metric over `n` pairs:
/// `{n, position, x, y, z, quat_distance, angle, roll, pitch, yaw}` (the names of
/// [`armtwin_core::metrics::METRIC_NAMES`]; metres, radians, quaternion distance).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StatsSetJson {
    /// Pairs counted.
    pub n: u64,
    /// Position distance (m).
    pub position: StatsJson,
    /// |dx| (m).
    pub x: StatsJson,
    /// |dy| (m).
    pub y: StatsJson,
    /// |dz| (m).
    pub z: StatsJson,
    /// Quaternion distance.
    pub quat_distance: StatsJson,
    /// Rotation angle (rad).
    pub angle: StatsJson,
    /// |droll| (rad).
    pub roll: StatsJson,
    /// |dpitch| (rad).
    pub pitch: StatsJson,
    /// |dyaw| (rad).
    pub yaw: StatsJson,
}

impl StatsSetJson {
    /// Writes `n` and each metric's `{mae, rmse, max}` into `object`, in field order.
    fn write_members(&self, object: &mut FlatObject) {
        object.unsigned("n", self.n);
        // The order of `METRIC_NAMES`, as the fields.
        let stats = [
            &self.position,
            &self.x,
            &self.y,
            &self.z,
            &self.quat_distance,
            &self.angle,
            &self.roll,
            &self.pitch,
            &self.yaw,
        ];
        for (name, stats) in METRIC_NAMES.into_iter().zip(stats) {
            object.open(name);
            object.number("mae", stats.mae);
            object.number("rmse", stats.rmse);
            object.number("max", stats.max);
            object.close();
        }
    }
}

impl From<&StatsSet> for StatsSetJson {
    fn from(set: &StatsSet) -> Self {
        // The order of `METRIC_NAMES`.
        let [position, x, y, z, quat_distance, angle, roll, pitch, yaw] =
            set.stats.each_ref().map(StatsJson::from);
        Self {
            n: set.n,
            position,
            x,
            y,
            z,
            quat_distance,
            angle,
            roll,
            pitch,
            yaw,
        }
    }
}

/// Statistics over the sliding window: `{seconds, n, position, …, yaw}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WindowJson {
    /// Window length (s) of source time.
    pub seconds: f64,
    /// The statistics over the window.
    #[serde(flatten)]
    pub stats: StatsSetJson,
}

/// A robot's metrics: `{robot, t, paired, unpaired, rejected, epoch, cumulative, window}`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MetricsMessage {
    /// Robot id.
    pub robot: String,
    /// Newest source time (s) seen for the robot.
    pub t: f64,
    /// Measured poses paired with the twin.
    pub paired: u64,
    /// Measured poses that could not be paired.
    pub unpaired: u64,
    /// Inputs rejected.
    pub rejected: u64,
    /// The metrics epoch (one more each time the robot's model was replaced).
    pub epoch: u64,
    /// Since start or the last reset.
    pub cumulative: StatsSetJson,
    /// Over the sliding window.
    pub window: WindowJson,
    /// The robot's effort ([`super::effort_summary_json`]), when it is watched; absent
    /// otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub effort: Option<Value>,
}

impl MetricsMessage {
    /// The message of a metrics readout.
    #[must_use]
    pub fn new(readout: &MetricsReadout) -> Self {
        Self {
            effort: readout
                .effort
                .as_deref()
                .map(|summary| super::effort_summary_json(&readout.robot, summary)),
            ..Self::without_effort(readout)
        }
    }

    /// The message of a metrics readout, leaving out its effort (which the state answer shows
    /// beside the metrics).
    #[must_use]
    pub fn without_effort(readout: &MetricsReadout) -> Self {
        Self {
            robot: readout.robot.clone(),
            t: readout.stamp_s,
            paired: readout.paired,
            unpaired: readout.unpaired,
            rejected: readout.rejected,
            epoch: readout.epoch,
            cumulative: StatsSetJson::from(&readout.cumulative),
            window: WindowJson {
                seconds: readout.window_s,
                stats: StatsSetJson::from(&readout.window),
            },
            effort: None,
        }
    }

    /// The message's JSON: the bytes [`to_json_bytes`](super::to_json_bytes) writes for it, written directly (each
    /// tracked robot sends one every metrics period).
    #[must_use]
    pub fn to_json_bytes(&self) -> Vec<u8> {
        let mut object = FlatObject::with_capacity(METRICS_JSON_CAPACITY);
        object.string("robot", &self.robot);
        object.number("t", self.t);
        object.unsigned("paired", self.paired);
        object.unsigned("unpaired", self.unpaired);
        object.unsigned("rejected", self.rejected);
        object.unsigned("epoch", self.epoch);
        object.open("cumulative");
        self.cumulative.write_members(&mut object);
        object.close();
        object.open("window");
        object.number("seconds", self.window.seconds);
        self.window.stats.write_members(&mut object);
        object.close();
        if let Some(effort) = &self.effort {
            object.value("effort", effort);
        }
        object.finish()
    }
}

/// A stamped pose: `{t, x, y, z, roll, pitch, yaw, qx, qy, qz, qw}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StampedPoseJson {
    /// Source time (s).
    pub t: f64,
    /// The pose.
    #[serde(flatten)]
    pub pose: PoseFields,
}

/// Stamped joint angles: `{t, q}` (rad).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StampedJointsJson {
    /// Source time (s).
    pub t: f64,
    /// Joint angles (rad).
    pub q: Vec<f64>,
}

/// Whether each alarm is active: `{position, angle}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct AlarmsJson {
    /// Position alarm.
    pub position: bool,
    /// Angle alarm.
    pub angle: bool,
}

/// A robot's state view: `{robot, model, calibration, tool, frame, joints, twin, measured,
/// alarms, metrics}`; `calibration`, `joints`, `twin`, `measured` are `null` until known.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StateMessage {
    /// Robot id.
    pub robot: String,
    /// Arm model name (`ur10e`, or a custom arm's name).
    pub model: String,
    /// Where the factory calibration came from; `null` for the nominal arm.
    pub calibration: Option<String>,
    /// Tool offset `[x, y, z, rx, ry, rz]` (m, rotation vector in rad) in the flange frame.
    pub tool: [f64; 6],
    /// The frame poses are expressed in.
    pub frame: &'static str,
    /// Last valid joint sample.
    pub joints: Option<StampedJointsJson>,
    /// The latest of each part of the joint state sent beside the angles (`t` the stamp of the
    /// last sample that brought any), or `null` when none came.
    pub joint_state: Option<Value>,
    /// Last twin pose.
    pub twin: Option<StampedPoseJson>,
    /// Last measured pose, in the output frame.
    pub measured: Option<StampedPoseJson>,
    /// Alarm states.
    pub alarms: AlarmsJson,
    /// Current metrics (without the effort, which is beside them).
    pub metrics: MetricsMessage,
    /// The robot's effort ([`super::effort_summary_json`]), when it is watched; absent
    /// otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub effort: Option<Value>,
    /// What a gateway read of the robot's controller (its TCP, model and serial number), once
    /// one did; absent otherwise. The service fills it in: the pipeline does not know it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub controller: Option<Value>,
}

impl StateMessage {
    /// The message of a pipeline state view.
    #[must_use]
    pub fn new(state: &RobotState<'_>) -> Self {
        let stamped = |&(t, pose): &(f64, &PoseReadout)| StampedPoseJson {
            t,
            pose: PoseFields::from(pose),
        };
        let Alarms { position, angle } = state.alarms_active;
        Self {
            robot: state.robot.to_owned(),
            model: state.model.arm().name.clone(),
            calibration: state
                .model
                .calibration()
                .map(|calibration| calibration.source_name.clone()),
            tool: state.model.tool().to_ur_pose(),
            frame: state.model.frame().as_str(),
            joints: state
                .last_joints
                .map(|(t, q)| StampedJointsJson { t, q: q.to_vec() }),
            joint_state: state
                .last_state
                .map(|(t, joint_state)| joint_state_json(t, joint_state)),
            twin: state.last_twin_pose.as_ref().map(stamped),
            measured: state.last_measured.as_ref().map(stamped),
            alarms: AlarmsJson { position, angle },
            metrics: MetricsMessage::without_effort(&state.metrics),
            effort: state
                .metrics
                .effort
                .as_deref()
                .map(|summary| super::effort_summary_json(state.robot, summary)),
            controller: None,
        }
    }
}

/// A joint state as the state answer shows it: its wire fields, and the status bits by name.
#[must_use]
pub fn joint_state_json(stamp_s: f64, state: &JointState) -> Value {
    let mut fields = serde_json::Map::new();
    fields.insert("t".to_owned(), json!(stamp_s));
    for (quantity, values) in state.quantities() {
        fields.insert(quantity.name().to_owned(), json!(values));
    }
    if let Some(status) = &state.status {
        fields.insert("robot_mode".to_owned(), json!(status.robot_mode));
        fields.insert("safety_mode".to_owned(), json!(status.safety_mode));
        fields.insert("status_bits".to_owned(), json!(status.status_bits));
        fields.insert("speed_scaling".to_owned(), json!(status.speed_scaling));
        fields.insert("power_on".to_owned(), json!(status.power_on()));
        fields.insert(
            "program_running".to_owned(),
            json!(status.program_running()),
        );
        fields.insert("freedrive".to_owned(), json!(status.freedrive()));
    }
    if let Some(payload) = &state.payload {
        fields.insert(
            "payload".to_owned(),
            json!({
                "mass_kg": payload.mass_kg,
                "cog_m": payload.cog_m,
                "inertia_kg_m2": payload.inertia_kg_m2,
            }),
        );
    }
    Value::Object(fields)
}

/// Error figures as written in the report (mm and mrad).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ErrorsJson {
    /// Samples.
    pub count: usize,
    /// Position MAE (mm).
    pub position_mae_mm: f64,
    /// Position RMSE (mm).
    pub position_rmse_mm: f64,
    /// Largest position error (mm).
    pub position_max_mm: f64,
    /// Rotation angle MAE (mrad).
    pub angle_mae_mrad: f64,
    /// Rotation angle RMSE (mrad).
    pub angle_rmse_mrad: f64,
    /// Largest rotation angle (mrad).
    pub angle_max_mrad: f64,
}

impl From<PoseErrors> for ErrorsJson {
    fn from(e: PoseErrors) -> Self {
        Self {
            count: e.count,
            position_mae_mm: e.position_mae_m * 1e3,
            position_rmse_mm: e.position_rmse_m * 1e3,
            position_max_mm: e.position_max_m * 1e3,
            angle_mae_mrad: e.angle_mae_rad * 1e3,
            angle_rmse_mrad: e.angle_rmse_rad * 1e3,
            angle_max_mrad: e.angle_max_rad * 1e3,
        }
    }
}

/// One parameter in the report.
#[derive(Debug, Clone, Serialize)]
pub struct ParameterJson {
    /// `delta_theta[1]`, `beta[2]`, `tool_x`, …
    pub name: String,
    /// Value (m or rad).
    pub value: f64,
    /// One standard deviation, if identified.
    pub std_dev: Option<f64>,
    /// Whether identified (false: fixed at zero).
    pub identified: bool,
}

/// Every candidate parameter of a fit, as written (the `calibrate` report and the live estimate).
#[must_use]
pub fn parameters_json(fit: &Identification) -> Vec<ParameterJson> {
    fit.parameters
        .iter()
        .map(|p| ParameterJson {
            name: p.name.clone(),
            value: p.value,
            std_dev: p.std_dev,
            identified: p.identified,
        })
        .collect()
}

/// The names of the parameters a fit left fixed.
#[must_use]
pub fn not_identifiable(parameters: &[ParameterJson]) -> Vec<String> {
    parameters
        .iter()
        .filter(|p| !p.identified)
        .map(|p| p.name.clone())
        .collect()
}

/// A live robot's self-calibration estimate, as published on `<prefix>/calibration/<robot>` and
/// answered by the `status` query: judged against the model the robot's twin runs.
#[derive(Debug, Clone, Serialize)]
pub struct EstimateMessage {
    /// Robot id.
    pub robot: String,
    /// `estimate`, or `refused` (then `error` says why and the figures are absent).
    pub status: &'static str,
    /// Why the pairs gave no estimate.
    pub error: Option<String>,
    /// The metrics epoch of the model it was judged against.
    pub epoch: u64,
    /// Pairs the robot's reservoir had taken into account.
    pub offered: u64,
    /// Pairs fitted.
    pub train_pairs: usize,
    /// Pairs judged on (other time blocks than the fitted ones).
    pub held_out_pairs: usize,
    /// The current model's held-out errors.
    pub current: Option<ErrorsJson>,
    /// The estimate's held-out errors.
    pub identified: Option<ErrorsJson>,
    /// Current over identified held-out position MAE (above 1: the estimate is better).
    pub improvement: Option<f64>,
    /// Every candidate parameter.
    pub parameters: Vec<ParameterJson>,
    /// Parameters fixed because the pairs cannot tell them apart.
    pub not_identifiable: Vec<String>,
    /// Standard deviation of each joint's angle over the fitted pairs (rad).
    pub joint_spread_rad: Option<[f64; 6]>,
    /// Condition number of the identified subset (column-scaled).
    pub condition_number: Option<f64>,
    /// The fitted or given tool `[x, y, z, rx, ry, rz]`.
    pub tool: Option<[f64; 6]>,
    /// The estimate as the controller's `calibration.conf`.
    pub calibration_conf: Option<String>,
}

impl EstimateMessage {
    /// The message of an estimate.
    #[must_use]
    pub fn estimate(robot: &str, epoch: u64, estimate: &Estimate) -> Self {
        let fit = &estimate.identification;
        let parameters = parameters_json(fit);
        Self {
            robot: robot.to_owned(),
            status: "estimate",
            error: None,
            epoch,
            offered: estimate.offered,
            train_pairs: estimate.train_pairs,
            held_out_pairs: estimate.held_out_current.count,
            current: Some(estimate.held_out_current.into()),
            identified: Some(estimate.held_out_identified.into()),
            improvement: Some(estimate.improvement()).filter(|v| v.is_finite()),
            not_identifiable: not_identifiable(&parameters),
            parameters,
            joint_spread_rad: Some(fit.excitation.joint_spread_rad),
            condition_number: Some(fit.excitation.condition_number).filter(|v| v.is_finite()),
            tool: Some(fit.tool.to_ur_pose()),
            calibration_conf: Some(estimate.deltas().to_conf_text(&format!(
                "Identified by armtwin self-calibration of robot {robot} from {} pairs, judged on {} held out.",
                estimate.train_pairs, estimate.held_out_current.count
            ))),
        }
    }

    /// The message of pairs that gave no estimate.
    #[must_use]
    pub fn refused(robot: &str, epoch: u64, batch: &CalibrationBatch, error: &FitError) -> Self {
        Self {
            robot: robot.to_owned(),
            status: "refused",
            error: Some(error.to_string()),
            epoch,
            offered: batch.offered,
            train_pairs: batch.train.len(),
            held_out_pairs: batch.held_out.len(),
            current: None,
            identified: None,
            improvement: None,
            parameters: Vec::new(),
            not_identifiable: Vec::new(),
            joint_spread_rad: None,
            condition_number: None,
            tool: None,
            calibration_conf: None,
        }
    }
}
