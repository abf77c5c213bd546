//! The pure pipeline without any transport: what the service, replay and validate all run.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]
#![allow(clippy::float_cmp, reason = "stamps are passed through unchanged")]

use std::collections::HashMap;
use std::sync::Arc;

use armtwin_core::kinematics::OutputFrame;
use armtwin_core::metrics::Metric;
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::sinks::Record;
use armtwin_core::pipeline::{
    AlarmConfig, EventDetail, EventKind, Pipeline, PipelineConfig, ReplaceModelError, Robot,
    RobotDirectory, RobotIndex, RobotSettings, Sink,
};
use armtwin_core::sample::JointSample;
use armtwin_core::self_calibration::ReservoirConfig;

fn pipeline() -> (Pipeline, Arc<RobotModel>, RobotDirectory) {
    let model = Arc::new(RobotModel::nominal("ur10e").expect("catalog"));
    let settings = RobotSettings {
        model: model.clone(),
        alarm: AlarmConfig::default(),
        sensors: Vec::new(),
        self_calibration: None,
        effort: None,
    };
    (
        Pipeline::new(PipelineConfig::default()),
        model,
        RobotDirectory::new(Some(settings), HashMap::new()),
    )
}

/// `id`'s handle, admitted under the default settings.
fn robot(directory: &mut RobotDirectory, id: &str) -> Robot {
    directory.admit(id).expect("default settings").clone()
}

/// Sends `robot`'s metrics if it has new results since its last ones.
fn publish_metrics_if_due(pipeline: &mut Pipeline, robot: &Robot, sink: &mut impl Sink) {
    if let Some(snapshot) = pipeline.take_due_metrics(robot.index()) {
        sink.metrics(robot, &snapshot);
    }
}

/// The ids of `robots`.
fn ids(pipeline: &Pipeline, robots: &[RobotIndex]) -> Vec<String> {
    robots
        .iter()
        .map(|&robot| pipeline.state(robot).expect("tracked").robot.to_owned())
        .collect()
}

fn sample(model: &RobotModel, q: [f64; 6], with_measured: bool) -> JointSample {
    JointSample {
        stamp_s: None,
        seq: None,
        q_rad: q.into_iter().collect(),
        measured: with_measured.then(|| model.pose(&q).expect("valid").readout()),
        state: None,
    }
}

#[test]
fn a_clock_restart_starts_alignment_and_window_afresh() {
    let (mut pipeline, model, mut directory) = pipeline();
    let r1 = robot(&mut directory, "r1");
    let mut sink = Record::default();
    let q = [0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
    for i in 0..20 {
        let t = 1000.0 + f64::from(i) * 0.01;
        pipeline.joints(
            &r1,
            "twin/joints/r1",
            t,
            &sample(&model, q, true),
            &mut sink,
        );
    }
    // A small step back is an out-of-order sample (one rejection, its measured part included)...
    pipeline.joints(
        &r1,
        "twin/joints/r1",
        1000.1,
        &sample(&model, q, true),
        &mut sink,
    );
    // ...a big one is the gateway restarting its clock: accepted, with an event.
    for i in 0..5 {
        let t = f64::from(i) * 0.01;
        pipeline.joints(
            &r1,
            "twin/joints/r1",
            t,
            &sample(&model, q, true),
            &mut sink,
        );
    }
    assert_eq!(
        sink.poses().count(),
        25,
        "every sample but the out-of-order one"
    );
    assert_eq!(sink.deviations().count(), 25);
    let kinds: Vec<EventKind> = sink.events().map(|e| e.kind).collect();
    assert_eq!(kinds, [EventKind::Rejected, EventKind::Restart]);
    assert!(matches!(
        sink.events().nth(1).map(|e| e.detail),
        Some(EventDetail::Restart { from_s, to_s }) if (from_s - 1000.19).abs() < 1e-9 && to_s == 0.0
    ));
    let metrics = pipeline.state(r1.index()).expect("tracked").metrics;
    assert_eq!(metrics.paired, 25);
    assert_eq!(metrics.rejected, 1);
    assert_eq!(metrics.cumulative.n, 25);
    assert_eq!(metrics.window.n, 5, "the window restarted with the clock");
    assert!((metrics.stamp_s - 0.04).abs() < 1e-12);
    // Pose seq keeps counting without gaps across the restart.
    let seqs: Vec<u64> = sink.poses().map(|p| p.seq).collect();
    assert_eq!(seqs, (0..25).collect::<Vec<u64>>());
}

/// A gateway that restarts counts `seq` from 0 again while its clock moves on: its samples are
/// taken at once, with one `restart` event; a resend (same seq and stamp) and an older stamp are
/// still refused.
#[test]
fn a_restarted_gateway_is_taken_at_once_and_a_resend_is_still_refused() {
    let (mut pipeline, model, mut directory) = pipeline();
    let r1 = robot(&mut directory, "r1");
    let mut sink = Record::default();
    let q = [0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
    let with_seq = |seq| JointSample {
        seq: Some(seq),
        ..sample(&model, q, true)
    };
    let run = |pipeline: &mut Pipeline, sink: &mut Record, start_s: f64| {
        for seq in 0..100_u32 {
            let t = start_s + f64::from(seq) * 0.01;
            pipeline.joints(&r1, "twin/joints/r1", t, &with_seq(u64::from(seq)), sink);
        }
    };
    run(&mut pipeline, &mut sink, 100.0);
    run(&mut pipeline, &mut sink, 101.0);
    assert_eq!(sink.poses().count(), 200, "both runs' samples");
    let restarts: Vec<EventDetail> = sink
        .events()
        .filter(|e| e.kind == EventKind::Restart)
        .map(|e| e.detail)
        .collect();
    assert_eq!(
        restarts,
        [EventDetail::SeqRestart {
            from_seq: 99,
            to_seq: 0
        }]
    );
    assert_eq!(sink.events().count(), 1, "no gap, no rejection");
    let metrics = pipeline.state(r1.index()).expect("tracked").metrics;
    assert_eq!(metrics.cumulative.n, 200, "cumulative metrics go on");
    assert_eq!(metrics.rejected, 0);
    // The next sample follows the new count: no gap, no event.
    pipeline.joints(&r1, "twin/joints/r1", 102.0, &with_seq(100), &mut sink);
    assert_eq!(sink.events().count(), 1);
    // A resend of it (same seq, same stamp) and an older stamp are refused.
    pipeline.joints(&r1, "twin/joints/r1", 102.0, &with_seq(100), &mut sink);
    pipeline.joints(&r1, "twin/joints/r1", 101.5, &with_seq(3), &mut sink);
    let causes: Vec<&str> = sink
        .events()
        .filter_map(|e| match e.detail {
            EventDetail::Rejected { cause } => Some(cause.as_str()),
            _ => None,
        })
        .collect();
    assert_eq!(causes, ["duplicate_stamp", "out_of_order"]);
    assert_eq!(sink.poses().count(), 201);
}

#[test]
fn finish_reports_waiting_measurements_and_sends_final_metrics() {
    let (mut pipeline, model, mut directory) = pipeline();
    let r1 = robot(&mut directory, "r1");
    let mut sink = Record::default();
    let q = [0.0, -1.0, 1.0, -1.0, 1.0, 0.0];
    pipeline.joints(
        &r1,
        "twin/joints/r1",
        1.0,
        &sample(&model, q, false),
        &mut sink,
    );
    let pose = model.pose(&q).expect("valid").readout();
    pipeline.measured(
        &r1,
        "twin/measured/r1",
        armtwin_core::pipeline::MeasuredStream::Robot,
        1.5,
        &pose,
        &mut sink,
    );
    assert_eq!(
        sink.events().count(),
        0,
        "it waits for a later joint sample"
    );
    pipeline.finish(&mut sink);
    assert!(matches!(
        sink.events().next().map(|e| (e.kind, e.detail)),
        Some((
            EventKind::Unpaired,
            EventDetail::Unpaired {
                cause: "stream_ended",
                ..
            },
        ))
    ));
    let last = sink.metrics().last().expect("final metrics");
    assert_eq!((last.paired, last.unpaired), (0, 1));
}

#[test]
fn streams_keep_their_own_stamp_order_and_the_window_ages_without_pairs() {
    let (mut pipeline, model, mut directory) = pipeline();
    let r1 = robot(&mut directory, "r1");
    let mut sink = Record::default();
    let q = [0.2, -1.1, 1.0, -1.2, 1.0, 0.3];
    let pose = model.pose(&q).expect("valid").readout();
    // Joints with the controller's pose at 10 ms, a second stream (a sensor) 3 ms later each time.
    for i in 0..100 {
        let t = f64::from(i) * 0.01;
        pipeline.joints(
            &r1,
            "twin/joints/r1",
            t,
            &sample(&model, q, true),
            &mut sink,
        );
        pipeline.measured(
            &r1,
            "mocap/r1",
            armtwin_core::pipeline::MeasuredStream::Sensor(0),
            t - 0.007,
            &pose,
            &mut sink,
        );
    }
    let metrics = pipeline.state(r1.index()).expect("tracked").metrics;
    assert_eq!(
        metrics.rejected,
        0,
        "{:?}",
        sink.events().collect::<Vec<_>>()
    );
    // The first sensor pose (t = -0.007) precedes every joint sample; the others pair.
    assert_eq!((metrics.paired, metrics.unpaired), (199, 1));
    // Pairs stop, joints go on for 20 s: the 10 s window empties, cumulative keeps everything.
    for i in 100..2100 {
        let t = f64::from(i) * 0.01;
        pipeline.joints(
            &r1,
            "twin/joints/r1",
            t,
            &sample(&model, q, false),
            &mut sink,
        );
    }
    let metrics = pipeline.state(r1.index()).expect("tracked").metrics;
    assert_eq!(metrics.window.n, 0);
    assert_eq!(metrics.cumulative.n, 199);
    assert!((metrics.stamp_s - 20.99).abs() < 1e-9);
}

#[test]
fn a_resent_message_is_one_rejection_and_bad_stamps_do_not_move_time() {
    let (mut pipeline, model, mut directory) = pipeline();
    let r1 = robot(&mut directory, "r1");
    let mut sink = Record::default();
    let q = [0.0, -1.0, 1.0, -1.0, 1.0, 0.0];
    pipeline.joints(
        &r1,
        "twin/joints/r1",
        1.0,
        &sample(&model, q, true),
        &mut sink,
    );
    pipeline.joints(
        &r1,
        "twin/joints/r1",
        1.0,
        &sample(&model, q, true),
        &mut sink,
    );
    let mut beyond_limits = sample(&model, q, false);
    beyond_limits.q_rad[2] = 9.0;
    pipeline.joints(&r1, "twin/joints/r1", 1e9, &beyond_limits, &mut sink);
    let metrics = pipeline.state(r1.index()).expect("tracked").metrics;
    assert_eq!(
        metrics.rejected,
        2,
        "{:?}",
        sink.events().collect::<Vec<_>>()
    );
    assert_eq!(metrics.paired, 1);
    assert_eq!(
        metrics.stamp_s, 1.0,
        "a refused sample does not move source time"
    );
}

#[test]
fn periodic_metrics_go_out_once_per_robot_with_new_results() {
    let (mut pipeline, model, mut directory) = pipeline();
    let r1 = robot(&mut directory, "r1");
    let mut sink = Record::default();
    let q = [0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
    let r2 = robot(&mut directory, "r2");
    for robot in [&r1, &r2] {
        pipeline.joints(
            robot,
            &format!("twin/joints/{}", robot.id()),
            1.0,
            &sample(&model, q, true),
            &mut sink,
        );
    }
    let mut due = ids(&pipeline, &pipeline.robots_with_due_metrics());
    due.sort();
    assert_eq!(due, ["r1", "r2"]);
    for robot in [&r1, &r2] {
        publish_metrics_if_due(&mut pipeline, robot, &mut sink);
        // A second call before new results sends nothing.
        publish_metrics_if_due(&mut pipeline, robot, &mut sink);
    }
    let robots: Vec<&str> = sink.metrics().map(|m| m.robot.as_str()).collect();
    assert_eq!(robots, ["r1", "r2"]);
    assert!(pipeline.robots_with_due_metrics().is_empty());
    pipeline.joints(
        &r2,
        "twin/joints/r2",
        1.01,
        &sample(&model, q, true),
        &mut sink,
    );
    assert_eq!(ids(&pipeline, &pipeline.robots_with_due_metrics()), ["r2"]);
    // Unknown robots have no metrics to send.
    let nobody = robot(&mut directory, "nobody");
    publish_metrics_if_due(&mut pipeline, &nobody, &mut sink);
    assert_eq!(sink.metrics().count(), 2);
    // Taken instead of sent (the service encodes and sends them outside its lock): counted as
    // sent all the same.
    assert!(pipeline.take_due_metrics(r1.index()).is_none());
    let taken = pipeline.take_due_metrics(r2.index()).expect("new results");
    assert_eq!((taken.robot.as_str(), taken.stamp_s), ("r2", 1.01));
    assert!(pipeline.take_due_metrics(r2.index()).is_none());
    assert!(pipeline.robots_with_due_metrics().is_empty());
    assert_eq!(sink.metrics().count(), 2);
}

#[test]
fn a_replaced_model_starts_a_new_epoch_and_self_calibration_keeps_only_accepted_pairs() {
    let model = Arc::new(RobotModel::nominal("ur10e").expect("catalog"));
    let settings = RobotSettings {
        model: model.clone(),
        alarm: AlarmConfig::default(),
        sensors: Vec::new(),
        self_calibration: Some(ReservoirConfig {
            min_spacing_s: 0.0,
            ..ReservoirConfig::default()
        }),
        effort: None,
    };
    let mut directory = RobotDirectory::new(Some(settings), HashMap::new());
    let mut pipeline = Pipeline::new(PipelineConfig::default());
    let r1 = robot(&mut directory, "r1");
    let mut sink = Record::default();
    let q = [0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
    for i in 0..10 {
        let t = f64::from(i) * 0.01;
        pipeline.joints(&r1, "k", t, &sample(&model, q, true), &mut sink);
    }
    // A measured pose 200 m off is refused, and not kept for calibration either.
    let mut far = sample(&model, q, true);
    far.measured.as_mut().expect("measured").position_m[0] += 200.0;
    pipeline.joints(&r1, "k", 0.2, &far, &mut sink);
    let reservoir = pipeline.reservoir(r1.index()).expect("kept");
    assert_eq!(
        (reservoir.offered(), reservoir.kept().0 + reservoir.kept().1),
        (10, 10)
    );
    assert_eq!(
        pipeline.state(r1.index()).expect("tracked").metrics.paired,
        10
    );

    // Another model (here: a tool 0.1 m along the flange): the old epoch's final metrics, the
    // event, counters from zero, poses from the new model.
    let tooled = Arc::new(
        RobotModel::new(
            model.arm().clone(),
            None,
            armtwin_core::kinematics::TcpOffset::from_ur_pose([0.0, 0.0, 0.1, 0.0, 0.0, 0.0])
                .expect("finite"),
            OutputFrame::Base,
        )
        .expect("model"),
    );
    let last = pipeline
        .replace_model(r1.index(), Arc::clone(&tooled), &mut sink)
        .expect("tracked");
    assert_eq!((last.epoch, last.paired), (0, 10));
    assert_eq!(sink.metrics().last().map(|m| m.paired), Some(10));
    assert!(matches!(
        sink.events().last().map(|e| (e.kind, e.detail)),
        Some((EventKind::Epoch, EventDetail::Epoch { epoch: 1 }))
    ));
    let state = pipeline.state(r1.index()).expect("tracked");
    assert_eq!((state.metrics.epoch, state.metrics.paired), (1, 0));
    assert!(Arc::ptr_eq(
        pipeline.model(r1.index()).expect("model"),
        &tooled
    ));
    // The controller still reports the flange: now 0.1 m from the twin.
    pipeline.joints(&r1, "k", 0.3, &sample(&model, q, true), &mut sink);
    let state = pipeline.state(r1.index()).expect("tracked");
    assert_eq!(state.metrics.paired, 1);
    assert!((state.metrics.cumulative.of(Metric::Position).max - 0.1).abs() < 1e-12);
    // A robot without a twin has no model to replace.
    let r2 = robot(&mut directory, "r2");
    assert_eq!(
        pipeline.replace_model(r2.index(), tooled, &mut sink).err(),
        Some(ReplaceModelError::NotTracked)
    );
}

#[test]
fn a_twin_takes_a_model_of_another_joint_count_and_computes_with_it() {
    let (mut pipeline, model, mut directory) = pipeline();
    let r1 = robot(&mut directory, "r1");
    let mut sink = Record::default();
    let q = [0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
    pipeline.joints(&r1, "k", 0.0, &sample(&model, q, true), &mut sink);
    pipeline.joints(&r1, "k", 0.01, &sample(&model, q, false), &mut sink);
    let panda_urdf = include_str!("../../../tests/data/urdf/panda.urdf");
    let arm = armtwin_core::model::urdf::arm_from_urdf(
        panda_urdf,
        "panda.urdf",
        Some("panda_link0"),
        Some("panda_hand_tcp"),
    )
    .expect("panda");
    let panda =
        Arc::new(RobotModel::new(arm, None, *model.tool(), OutputFrame::Base).expect("model"));
    pipeline
        .replace_model(r1.index(), Arc::clone(&panda), &mut sink)
        .expect("no arm-specific monitor rides on the joints");
    let q7 = [0.1, -0.5, 0.2, -2.0, 0.1, 1.5, 0.7];
    let seven = JointSample {
        stamp_s: None,
        seq: None,
        q_rad: q7.into_iter().collect(),
        measured: Some(panda.pose(&q7).expect("valid").readout()),
        state: None,
    };
    pipeline.joints(&r1, "k", 0.02, &seven, &mut sink);
    let state = pipeline.state(r1.index()).expect("tracked");
    assert_eq!(
        (
            state.metrics.epoch,
            state.metrics.paired,
            state.metrics.rejected
        ),
        (1, 1, 0)
    );
    let (_, pose) = state.last_twin_pose.expect("a pose");
    let expected = panda.pose(&q7).expect("valid").readout();
    assert_eq!(pose.position_m, expected.position_m);
    // Six joints now are refused, as any sample of the wrong count.
    pipeline.joints(&r1, "k", 0.03, &sample(&model, q, false), &mut sink);
    assert_eq!(
        pipeline
            .state(r1.index())
            .expect("tracked")
            .metrics
            .rejected,
        1
    );
}
