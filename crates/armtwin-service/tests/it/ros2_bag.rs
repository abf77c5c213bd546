//! rosbag2 recordings offline: the MCAP and sqlite3 bags written by `rosbags` read into the rows
//! their CSV export reads into, and validate with the same metrics (`armtwin validate` on a bag is
//! tested with the binary, in armtwin-cli).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use armtwin_codec::recording::{self, Format, Recording};
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{AlarmConfig, PipelineConfig, RobotSettings};
use armtwin_offline::rosbag::{self, BagError, BagOptions, BagTopics, Storage};
use armtwin_offline::validate::{Validation, validate};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/ros2")
}

fn run(recording: &Recording) -> Validation {
    let settings = RobotSettings {
        model: Arc::new(RobotModel::nominal("ur10e").expect("catalog")),
        alarm: AlarmConfig::default(),
        sensors: Vec::new(),
        self_calibration: None,
        effort: None,
    };
    let times = recording::source_times(recording, None);
    validate(
        recording,
        &times,
        PipelineConfig::default(),
        settings,
        |_| {},
    )
}

fn csv_recording() -> Recording {
    let text = std::fs::read_to_string(fixtures().join("ur10e_lasttest_head.csv")).expect("CSV");
    recording::read(&text).expect("a ROS 2 export")
}

#[test]
fn both_bags_read_into_the_rows_of_their_csv_and_validate_alike() {
    let csv = csv_recording();
    assert_eq!(csv.entries.len(), 400);
    let expected = run(&csv);
    assert_eq!(expected.metrics.paired, 400);
    for (directory, storage) in [
        ("ur10e_lasttest_head_mcap", Storage::Mcap),
        ("ur10e_lasttest_head_sqlite3", Storage::Sqlite3),
    ] {
        let bag = rosbag::read(&fixtures().join(directory), &BagOptions::default())
            .unwrap_or_else(|e| panic!("{directory}: {e}"));
        assert_eq!(bag.storage, storage);
        assert_eq!(bag.summary.joint_messages, 400, "{directory}");
        assert_eq!(bag.summary.paired_poses, 400, "{directory}");
        assert_eq!(bag.summary.unmatched_poses, 0, "{directory}");
        assert!(bag.summary.pose_errors.is_empty(), "{directory}");
        assert_eq!(bag.recording.format, Format::Rosbag2);
        assert!(bag.recording.has_pose);
        // Row for row what the CSV holds (only the line numbers differ: a bag has messages).
        for (from_bag, from_csv) in bag.recording.entries.iter().zip(&csv.entries) {
            let (from_bag, from_csv) = (from_bag.as_ref().unwrap(), from_csv.as_ref().unwrap());
            assert_eq!(from_bag.stamp_s, from_csv.stamp_s, "{directory}");
            assert_eq!(from_bag.q, from_csv.q, "{directory}");
            assert_eq!(from_bag.pose, from_csv.pose, "{directory}");
        }
        let validation = run(&bag.recording);
        assert_eq!(validation.metrics, expected.metrics, "{directory}");
        assert_eq!(validation.events, expected.events, "{directory}");
        assert_eq!(validation.rows.len(), expected.rows.len());
        for (a, b) in validation.rows.iter().zip(&expected.rows) {
            assert_eq!((a.stamp_s, a.twin, a.paired), (b.stamp_s, b.twin, b.paired));
        }
    }
}

#[test]
fn the_storage_file_alone_reads_as_its_bag() {
    let file = fixtures().join("ur10e_lasttest_head_sqlite3/ur10e_lasttest_head_sqlite3.db3");
    assert!(rosbag::is_bag(&file));
    let bag = rosbag::read(&file, &BagOptions::default()).expect("readable");
    assert_eq!(bag.summary.joint_messages, 400);
    assert!(!rosbag::is_bag(&fixtures().join("ur10e_lasttest_head.csv")));
}

#[test]
fn topics_are_overridable_and_a_wrong_one_is_named() {
    let bag = fixtures().join("ur10e_lasttest_head_mcap");
    let options = BagOptions {
        topics: BagTopics {
            joint_states: "/ur/joint_states".to_owned(),
            ..BagTopics::default()
        },
        ..BagOptions::default()
    };
    let error = rosbag::read(&bag, &options).unwrap_err();
    assert!(matches!(error, BagError::NoTopic { .. }), "{error}");
    assert_eq!(
        error.to_string(),
        "topic '/ur/joint_states' is not in the bag; it has: /joint_states, /tcp_pose_broadcaster/pose"
    );
    // The pose topic read as joints: a type mismatch, named.
    let options = BagOptions {
        topics: BagTopics {
            joint_states: "/tcp_pose_broadcaster/pose".to_owned(),
            pose: "/none".to_owned(),
        },
        ..BagOptions::default()
    };
    let error = rosbag::read(&bag, &options).unwrap_err();
    assert!(matches!(error, BagError::TopicType { .. }), "{error}");
    // A tf_prefix the bag's joints lack: every row is refused by name, none is dropped.
    let options = BagOptions {
        tf_prefix: "alice_".to_owned(),
        ..BagOptions::default()
    };
    let bag = rosbag::read(&bag, &options).expect("readable");
    assert_eq!(bag.recording.entries.len(), 400);
    let malformed = bag.recording.entries[0].as_ref().unwrap_err();
    assert_eq!(
        malformed.problem,
        "missing_joint: missing joint 'alice_shoulder_pan_joint'"
    );
    assert_eq!(
        bag.summary.pose_errors.len(),
        400,
        "the poses are in 'base'"
    );
}
