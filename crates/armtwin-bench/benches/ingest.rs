//! armtwin's own work per sample, without Zenoh: what `armtwin serve` does inside the receive
//! callback for the service benchmark's load (`armtwin-bench load`'s payloads, rendered by the
//! same code in `armtwin_bench::ingest_fixture`). One sample is a joint message and its measured
//! pose, into the pipeline through the service's entry points (`ingest::joint_message` /
//! `ingest::measured_message`), and the outputs encoded as the service encodes them (a pose and a
//! deviation message). Also each part alone: decoding, encoding (the fixed-layout writer the
//! service uses, and `serde_json` writing the same bytes, as the baseline), and a robot's metrics
//! message; the binary messages (Zenoh's serialization) next to their JSON counterparts, decoded
//! by armtwin's reader and by zenoh-ext's `z_deserialize`.
//!
//! `cargo bench -p armtwin-bench --bench ingest`
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
use std::hint::black_box;
use std::time::{Duration, Instant};

use armtwin_bench::fleet::robot_id;
use armtwin_bench::ingest_fixture::{Encode, Load, RENDERED};
use armtwin_bench::workload::Workload;
use armtwin_codec::{PoseFields, cdr, json, zser};
use armtwin_core::kinematics::OutputFrame;
use armtwin_core::metrics::Deviation;
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{Discard, Sink};
use armtwin_mesh::ros2;
use criterion::{Criterion, criterion_group, criterion_main};
use zenoh::bytes::ZBytes;

/// Time of `iterations` samples into fresh pipelines through `sink`.
fn run(load: &Load, iterations: u64, sink: &mut impl Sink) -> Duration {
    let mut elapsed = Duration::ZERO;
    let mut left = iterations as usize;
    while left > 0 {
        let chunk = left.min(RENDERED);
        let mut pipeline = Load::pipeline();
        let start = Instant::now();
        for index in 0..chunk {
            load.joints(&mut pipeline, index, sink);
            load.measured(&mut pipeline, index, sink);
        }
        elapsed += start.elapsed();
        left -= chunk;
    }
    elapsed
}

fn sample(c: &mut Criterion) {
    let load = Load::starting_at(0);
    c.bench_function("sample/pipeline", |b| {
        b.iter_custom(|iterations| run(&load, iterations, &mut Discard));
    });
    c.bench_function("sample/pipeline_and_encoding", |b| {
        let mut sink = Encode::default();
        b.iter_custom(|iterations| run(&load, iterations, &mut sink));
    });
}

fn parts(c: &mut Criterion) {
    let load = Load::starting_at(0);
    let (_, joints, measured) = &load.samples[7];
    c.bench_function("decode/joints", |b| {
        b.iter(|| json::decode_joints(black_box(joints.as_bytes()), 6));
    });
    // The UR driver's `/joint_states` as CDR (six joints in the driver's order, with velocity
    // and effort), written by `rosbags`: the binary counterpart of `decode/joints`.
    let joint_state: &[u8] =
        include_bytes!("../../../tests/data/ros2/joint_state_driver_order.cdr");
    let joint_names = cdr::JointNames::ur("");
    c.bench_function("decode/joint_state_cdr", |b| {
        b.iter(|| cdr::decode_joint_state(black_box(joint_state), &joint_names, None));
    });
    // What a ROS 2 joint sample on an `rmw_zenoh` key adds: its attachment (sequence number,
    // source time, 16-byte gid), read before the twin lock.
    let attachment = ros2::encode_attachment(1042, 1_748_954_669_250_000_000, &[7; 16]);
    c.bench_function("decode/rmw_attachment", |b| {
        b.iter(|| ros2::Attachment::parse(black_box(&attachment)));
    });
    c.bench_function("decode/measured", |b| {
        b.iter(|| json::decode_measured(black_box(measured.as_bytes())));
    });
    binary_decoding(c);
    let model = RobotModel::nominal("ur10e").expect("catalog");
    let twin = model
        .pose(&[0.1, -1.2, 1.4, -0.3, 1.1, 0.5])
        .expect("within limits")
        .readout();
    let mut measured = twin;
    measured.position_m[0] += 0.0004;
    let deviation = Deviation::between(&twin, &measured);
    // What the service does for each twin pose: build the message (the robot id copied), write it.
    let pose_message = || {
        json::PoseMessage::new(
            black_box(&load.robot).as_str(),
            1000.25,
            42,
            OutputFrame::Base.as_str(),
            black_box(&twin),
        )
    };
    c.bench_function("encode/pose", |b| {
        b.iter(|| pose_message().to_json_bytes());
    });
    // The twin pose for ROS tools, beside its JSON message: a `PoseStamped` and its attachment.
    c.bench_function("encode/pose_stamped_cdr", |b| {
        b.iter(|| {
            let payload = cdr::encode_pose_stamped(1000.25, "base", black_box(&twin));
            let attachment = ros2::encode_attachment(42, 1_748_954_669_250_000_000, &[7; 16]);
            (payload, attachment)
        });
    });
    c.bench_function("encode/pose_serde_json", |b| {
        b.iter(|| json::to_json_bytes(&pose_message()));
    });
    c.bench_function("encode/deviation", |b| {
        b.iter(|| {
            let message = json::DeviationMessage::new(
                black_box(&load.robot).as_str(),
                1000.25,
                black_box(&deviation),
            );
            message.to_json_bytes()
        });
    });
    c.bench_function("encode/pose_zser", |b| {
        b.iter(|| zser::twin_pose_bytes(1000.25, 42, &PoseFields::from(black_box(&twin))));
    });
    c.bench_function("encode/deviation_zser", |b| {
        b.iter(|| zser::deviation_bytes(1000.25, black_box(&deviation)));
    });
}

/// The binary messages next to their JSON counterparts (same sample, same values): the joint
/// message alone (`decode/joints`' content plus the schema's `seq`), also through zenoh-ext's
/// `z_deserialize` (the same values into `Vec`s, no pose to build), and with its measured pose
/// embedded; the measured pose alone.
fn binary_decoding(c: &mut Criterion) {
    let workload = Workload::ur10e().expect("the ur10e's payloads");
    let binary = workload.joints_zser(7, 1000.07, 7, false);
    c.bench_function("decode/joints_zser", |b| {
        b.iter(|| zser::read_joints(black_box(&binary), 6));
    });
    let bytes = ZBytes::from(binary.clone());
    c.bench_function("decode/joints_zenoh_ext", |b| {
        b.iter(|| {
            let values: (f64, Vec<f64>, u64, Vec<f64>) =
                zenoh_ext::z_deserialize(black_box(&bytes)).expect("zenoh-ext reads its bytes");
            values
        });
    });
    let json = workload.joints_with_measured(7, 1000.07);
    c.bench_function("decode/joints_with_measured", |b| {
        b.iter(|| json::decode_joints(black_box(json.as_bytes()), 6));
    });
    let binary = workload.joints_zser(7, 1000.07, 7, true);
    c.bench_function("decode/joints_with_measured_zser", |b| {
        b.iter(|| zser::read_joints(black_box(&binary), 6));
    });
    let binary = workload.measured_zser(7, 1000.07);
    c.bench_function("decode/measured_zser", |b| {
        b.iter(|| zser::read_measured(black_box(&binary)));
    });
}

/// A metrics message with full-precision statistics, as a robot's metrics look.
fn metrics_message(robot: &str) -> json::MetricsMessage {
    let stats = |seed: f64| json::StatsJson {
        mae: 1e-3 * (1.1 + seed.sin()),
        rmse: 1e-3 * (1.2 + seed.cos()),
        max: 1e-3 * (2.3 + (seed * 1.7).sin()),
    };
    let set = |n: u64, seed: f64| json::StatsSetJson {
        n,
        position: stats(seed),
        x: stats(seed + 1.0),
        y: stats(seed + 2.0),
        z: stats(seed + 3.0),
        quat_distance: stats(seed + 4.0),
        angle: stats(seed + 5.0),
        roll: stats(seed + 6.0),
        pitch: stats(seed + 7.0),
        yaw: stats(seed + 8.0),
    };
    json::MetricsMessage {
        robot: robot.to_owned(),
        t: 1_234.567_891,
        paired: 123_456,
        unpaired: 3,
        rejected: 0,
        epoch: 0,
        cumulative: set(123_456, 0.3),
        window: json::WindowJson {
            seconds: 10.0,
            stats: set(1000, 0.7),
        },
        effort: None,
    }
}

fn metrics(c: &mut Criterion) {
    let message = metrics_message(&robot_id(0));
    c.bench_function("encode/metrics", |b| {
        b.iter(|| black_box(&message).to_json_bytes());
    });
    c.bench_function("encode/metrics_serde_json", |b| {
        b.iter(|| json::to_json_bytes(black_box(&message)));
    });
}

criterion_group!(benches, sample, parts, metrics);
criterion_main!(benches);
