//! The messages armtwin publishes in JSON: their exact field sets, and the fixed-layout writer
//! of the frequent ones against `serde_json` writing the same structs.

use std::collections::BTreeSet;

use armtwin_codec::json::{
    DeviationMessage, EventMessage, MetricsMessage, PoseMessage, StateMessage, StatsSetJson,
    WireError, decode_measured, to_json_bytes,
};
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::{Deviation, METRIC_NAMES, Stats, StatsSet};
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{
    Alarms, Event, EventDetail, EventKind, MetricsReadout, Reason, RejectCause, RobotState,
};
use nalgebra::UnitQuaternion;
use serde_json::Value;

use super::json::assert_same_pose;

fn keys(value: &Value) -> BTreeSet<&str> {
    value
        .as_object()
        .expect("an object")
        .keys()
        .map(String::as_str)
        .collect()
}

fn set(names: &[&'static str]) -> BTreeSet<&'static str> {
    names.iter().copied().collect()
}

fn parse(bytes: &[u8]) -> Value {
    serde_json::from_slice(bytes).expect("valid JSON")
}

fn readout() -> PoseReadout {
    PoseReadout::from_position_quaternion(
        [0.5, -0.25, 1.0],
        &UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
    )
}

fn stats_set(n: u64, offset: f64) -> StatsSet {
    StatsSet {
        n,
        stats: std::array::from_fn(|m| Stats {
            mae: offset + m as f64,
            rmse: offset + m as f64 + 0.5,
            max: offset + m as f64 + 0.75,
        }),
    }
}

fn metrics_readout() -> MetricsReadout {
    MetricsReadout {
        robot: "ur10e_1".to_owned(),
        stamp_s: 12.5,
        paired: 10,
        unpaired: 2,
        rejected: 1,
        cumulative: stats_set(10, 0.0),
        window: stats_set(4, 100.0),
        window_s: 5.0,
        epoch: 0,
        effort: None,
    }
}

const POSE_FIELDS: [&str; 10] = [
    "x", "y", "z", "roll", "pitch", "yaw", "qx", "qy", "qz", "qw",
];

fn stats_set_fields() -> BTreeSet<&'static str> {
    let mut fields = set(&METRIC_NAMES);
    fields.insert("n");
    fields
}

/// `value` as `serde_json` reads it back: its default parser may be one unit in the last place off.
fn assert_number(json: &Value, value: f64) {
    let got = json.as_f64().expect("a number");
    assert!(
        (got - value).abs() <= 2.0 * f64::EPSILON * value.abs(),
        "{got} vs {value}"
    );
}

#[test]
fn pose_message_fields() {
    let pose = readout();
    let bytes = to_json_bytes(&PoseMessage::new("ur10e_1", 2.5, 7, "base", &pose));
    let json = parse(&bytes);
    let mut expected = set(&["robot", "t", "seq", "frame"]);
    expected.extend(POSE_FIELDS);
    assert_eq!(keys(&json), expected);
    assert_eq!(json["robot"], "ur10e_1");
    assert_eq!(json["t"], 2.5);
    assert_eq!(json["seq"], 7);
    assert_eq!(json["frame"], "base");
    assert_eq!(json["x"], 0.5);
    assert_number(&json["roll"], pose.rpy.roll_rad);
    assert_number(&json["qw"], pose.quaternion_xyzw[3]);
    // Written in shortest round-trip form.
    let text = String::from_utf8(bytes).expect("UTF-8");
    assert!(
        text.contains(&format!(r#""roll":{:?}"#, pose.rpy.roll_rad)),
        "{text}"
    );
}

#[test]
fn a_published_pose_without_its_rpy_decodes_to_the_same_pose() {
    let pose = readout();
    let mut json = parse(&to_json_bytes(&PoseMessage::new(
        "r", 2.5, 7, "base", &pose,
    )));
    // A pose message carries two orientation forms; a measured message must carry one.
    assert_eq!(
        decode_measured(&to_json_bytes(&json))
            .expect_err("two forms")
            .kind(),
        "orientation_forms"
    );
    for key in ["roll", "pitch", "yaw"] {
        json.as_object_mut().expect("object").remove(key);
    }
    let back = decode_measured(&to_json_bytes(&json)).expect("valid");
    assert_eq!(back.stamp_s, Some(2.5));
    assert_same_pose(&back.pose, &pose);
}

#[test]
fn deviation_message_fields() {
    let twin = readout();
    let measured =
        PoseReadout::from_position_quaternion([0.4, -0.25, 1.0], &UnitQuaternion::identity());
    let deviation = Deviation::between(&twin, &measured);
    let json = parse(&to_json_bytes(&DeviationMessage::new(
        "ur10e_1", 3.0, &deviation,
    )));
    assert_eq!(
        keys(&json),
        set(&[
            "robot",
            "t",
            "dx",
            "dy",
            "dz",
            "position",
            "quat_distance",
            "angle",
            "droll",
            "dpitch",
            "dyaw"
        ])
    );
    assert_number(&json["dx"], deviation.dx_m);
    assert_number(&json["position"], deviation.position_m);
    assert_number(&json["angle"], deviation.angle_rad);
    assert_number(&json["dyaw"], deviation.dyaw_rad);
}

#[test]
fn event_message_fields() {
    let error = WireError::WrongType {
        field: "q3".to_owned(),
        expected: "a number",
        got: "a string".to_owned(),
    };
    let event = Event {
        robot: "ur10e_1",
        index: None,
        stamp_s: 4.0,
        kind: EventKind::Rejected,
        reason: Reason::Error(&error),
        key: Some("armtwin/joints/ur10e_1"),
        detail: EventDetail::Rejected {
            cause: RejectCause::Decode("wrong_type"),
        },
    };
    let json = parse(&to_json_bytes(&EventMessage::new(&event)));
    assert_eq!(
        keys(&json),
        set(&["robot", "t", "kind", "reason", "key", "detail"])
    );
    assert_eq!(json["kind"], "rejected");
    assert_eq!(json["key"], "armtwin/joints/ur10e_1");
    assert_eq!(json["detail"], serde_json::json!({"cause": "wrong_type"}));

    let details = [
        (
            EventKind::Alarm,
            EventDetail::Alarm {
                metric: "position",
                value: 0.02,
                threshold: 0.01,
            },
            vec!["metric", "value", "threshold"],
        ),
        (
            EventKind::Gap,
            EventDetail::StampGap { gap_s: 1.5 },
            vec!["gap_s"],
        ),
        (
            EventKind::Gap,
            EventDetail::SeqGap {
                expected: 4,
                got: 9,
            },
            vec!["expected", "got"],
        ),
        (
            EventKind::Unpaired,
            EventDetail::Unpaired {
                cause: "wait_expired",
                measured_s: 3.5,
            },
            vec!["cause", "measured_s"],
        ),
        (
            EventKind::Epoch,
            EventDetail::Epoch { epoch: 1 },
            vec!["epoch"],
        ),
    ];
    for (kind, detail, detail_fields) in details {
        let event = Event {
            kind,
            key: None,
            detail,
            ..event
        };
        let json = parse(&to_json_bytes(&EventMessage::new(&event)));
        assert_eq!(
            keys(&json),
            set(&["robot", "t", "kind", "reason", "detail"])
        );
        assert_eq!(json["kind"], kind.as_str());
        assert_eq!(keys(&json["detail"]), detail_fields.into_iter().collect());
    }

    let bare = EventMessage {
        detail: Value::Null,
        key: None,
        ..EventMessage::new(&event)
    };
    let json = parse(&to_json_bytes(&bare));
    assert_eq!(keys(&json), set(&["robot", "t", "kind", "reason"]));
}

#[test]
fn metrics_message_fields() {
    let json = parse(&to_json_bytes(&MetricsMessage::new(&metrics_readout())));
    assert_eq!(
        keys(&json),
        set(&[
            "robot",
            "t",
            "paired",
            "unpaired",
            "rejected",
            "epoch",
            "cumulative",
            "window"
        ])
    );
    assert_eq!(json["t"], 12.5);
    assert_eq!(
        (json["paired"].as_u64(), json["unpaired"].as_u64()),
        (Some(10), Some(2))
    );
    assert_eq!(json["rejected"], 1);
    assert_eq!(keys(&json["cumulative"]), stats_set_fields());
    let mut window_fields = stats_set_fields();
    window_fields.insert("seconds");
    assert_eq!(keys(&json["window"]), window_fields);
    assert_eq!(json["window"]["seconds"], 5.0);
    assert_eq!(json["window"]["n"], 4);
    // Each metric lands under its own name.
    for (m, name) in METRIC_NAMES.iter().enumerate() {
        let cumulative = &json["cumulative"][name];
        assert_eq!(keys(cumulative), set(&["mae", "rmse", "max"]));
        assert_eq!(cumulative["mae"], m as f64, "{name}");
        assert_eq!(cumulative["rmse"], m as f64 + 0.5, "{name}");
        assert_eq!(cumulative["max"], m as f64 + 0.75, "{name}");
        assert_eq!(json["window"][name]["mae"], 100.0 + m as f64, "{name}");
    }
    // The window's `seconds` comes first.
    let text =
        String::from_utf8(to_json_bytes(&MetricsMessage::new(&metrics_readout()))).expect("UTF-8");
    assert!(text.contains(r#""window":{"seconds":5.0,"n":4,"#), "{text}");
}

#[test]
fn stats_set_json_keeps_metric_order() {
    let json = serde_json::to_value(StatsSetJson::from(&stats_set(3, 0.0))).expect("serialises");
    assert_eq!(json["n"], 3);
    assert_eq!(json["yaw"]["mae"], 8.0);
    assert_eq!(json["position"]["max"], 0.75);
}

#[test]
fn state_message_fields() {
    let model = RobotModel::nominal("ur10e").expect("catalog model");
    let twin = readout();
    let q = [0.0, -1.0, 1.0, 0.0, 0.5, 0.0];
    let state = RobotState {
        robot: "ur10e_1",
        model: &model,
        last_joints: Some((2.0, &q)),
        last_twin_pose: Some((2.0, &twin)),
        last_measured: None,
        metrics: metrics_readout(),
        alarms_active: Alarms {
            position: true,
            angle: false,
        },
        last_state: None,
    };
    let json = parse(&to_json_bytes(&StateMessage::new(&state)));
    assert_eq!(
        keys(&json),
        set(&[
            "robot",
            "model",
            "calibration",
            "tool",
            "frame",
            "joints",
            "joint_state",
            "twin",
            "measured",
            "alarms",
            "metrics"
        ])
    );
    assert_eq!(json["model"], "ur10e");
    assert_eq!(json["calibration"], Value::Null);
    assert_eq!(json["frame"], "base");
    assert_eq!(
        json["tool"],
        serde_json::json!([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    );
    assert_eq!(keys(&json["joints"]), set(&["t", "q"]));
    assert_eq!(json["joints"]["q"][1], -1.0);
    let mut twin_fields = set(&["t"]);
    twin_fields.extend(POSE_FIELDS);
    assert_eq!(keys(&json["twin"]), twin_fields);
    assert_eq!(json["measured"], Value::Null);
    assert_eq!(
        json["alarms"],
        serde_json::json!({"position": true, "angle": false})
    );
    assert_eq!(
        json["metrics"],
        parse(&to_json_bytes(&MetricsMessage::new(&metrics_readout())))
    );
}

mod fixed_layout {
    //! The frequent messages' own writer against `serde_json` writing the same structs: the
    //! same bytes, for any values and any robot id.
    use armtwin_codec::PoseFields;
    use armtwin_codec::json::{
        DeviationMessage, MetricsMessage, PoseMessage, StatsJson, StatsSetJson, WindowJson,
        to_json_bytes,
    };
    use proptest::prelude::*;

    /// Any double, the awkward ones much more often than uniform bits would give them.
    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            any::<f64>(),
            -10.0..10.0f64,
            Just(0.0),
            Just(-0.0),
            Just(f64::NAN),
            Just(f64::INFINITY),
            Just(f64::NEG_INFINITY),
            Just(f64::MIN_POSITIVE / 8.0),
            Just(1e21),
            Just(1e-7),
            Just(f64::MAX),
        ]
    }

    /// Robot ids, including those that need escaping and non-ASCII ones.
    fn any_robot() -> impl Strategy<Value = String> {
        prop_oneof![
            "[a-z0-9_/-]{1,24}",
            any::<String>(),
            Just("quote\"back\\slash\u{1}tab\t".to_owned()),
            Just("unit\u{1f}separator\u{7f}delete".to_owned()),
            Just("zelle-3/roboter-ä/😀".to_owned()),
        ]
    }

    fn any_stats() -> impl Strategy<Value = StatsJson> {
        (any_f64(), any_f64(), any_f64()).prop_map(|(mae, rmse, max)| StatsJson { mae, rmse, max })
    }

    fn any_stats_set() -> impl Strategy<Value = StatsSetJson> {
        (any::<u64>(), prop::array::uniform9(any_stats())).prop_map(|(n, stats)| {
            let [position, x, y, z, quat_distance, angle, roll, pitch, yaw] = stats;
            StatsSetJson {
                n,
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
        })
    }

    proptest! {
        #[test]
        fn a_metrics_message_is_written_as_serde_json_writes_it(
            robot in any_robot(),
            t in any_f64(),
            counts in prop::array::uniform4(any::<u64>()),
            cumulative in any_stats_set(),
            seconds in any_f64(),
            window in any_stats_set(),
        ) {
            let [paired, unpaired, rejected, epoch] = counts;
            let message = MetricsMessage {
                robot,
                t,
                paired,
                unpaired,
                rejected,
                epoch,
                cumulative,
                window: WindowJson { seconds, stats: window },
                // Both with and without a watched robot's effort object.
                effort: (paired % 2 == 0)
                    .then(|| serde_json::json!({ "n": unpaired, "rms_nm": [t, seconds] })),
            };
            let fixed = message.to_json_bytes();
            let serde = to_json_bytes(&message);
            prop_assert_eq!(String::from_utf8_lossy(&fixed), String::from_utf8_lossy(&serde));
        }

        #[test]
        fn a_pose_message_is_written_as_serde_json_writes_it(
            robot in any_robot(),
            t in any_f64(),
            seq in any::<u64>(),
            base_link in any::<bool>(),
            values in prop::array::uniform10(any_f64()),
        ) {
            let [x, y, z, roll, pitch, yaw, qx, qy, qz, qw] = values;
            let message = PoseMessage {
                robot,
                t,
                seq,
                frame: if base_link { "base_link" } else { "base" },
                pose: PoseFields { x, y, z, roll, pitch, yaw, qx, qy, qz, qw },
            };
            let fixed = message.to_json_bytes();
            let serde = to_json_bytes(&message);
            prop_assert_eq!(String::from_utf8_lossy(&fixed), String::from_utf8_lossy(&serde));
        }

        #[test]
        fn a_deviation_message_is_written_as_serde_json_writes_it(
            robot in any_robot(),
            t in any_f64(),
            values in prop::array::uniform9(any_f64()),
        ) {
            let [dx, dy, dz, position, quat_distance, angle, droll, dpitch, dyaw] = values;
            let message = DeviationMessage {
                robot, t, dx, dy, dz, position, quat_distance, angle, droll, dpitch, dyaw,
            };
            let fixed = message.to_json_bytes();
            let serde = to_json_bytes(&message);
            prop_assert_eq!(String::from_utf8_lossy(&fixed), String::from_utf8_lossy(&serde));
        }
    }
}
