//! The flight recorder's cost, in ns per call: a joint sample's record built and pushed into a
//! robot's ring (the span full at 500 Hz; a block compressed into the log every few records),
//! the same with its paired measured pose; the cut of an incident of 15 s at 500 Hz (7 500
//! joint samples and their measured poses, read back from the log); and the time to write that
//! incident's file to memory and to a file. The rings' memory and the log's bytes per record at
//! 500 Hz are printed once (generated samples: a robot moving smoothly, not a recording).
//!
//! `cargo bench -p armtwin-recorder --bench recorder`
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are its own constants"
)]
use std::hint::black_box;
use std::io::Cursor;
use std::time::SystemTime;

use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::Deviation;
use armtwin_core::sample::{JointAngles, JointSample};
use armtwin_recorder::incident::{MEASURED_STRIDE, fill_measured, write_mcap};
use armtwin_recorder::{Incident, JointRecord, RecordRing, Spool, StoreSettings, Trigger};
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::UnitQuaternion;

/// Joint angles (rad) of a UR10e in a working pose.
const Q: [f64; 6] = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739];
const RATE_HZ: f64 = 500.0;
/// `[recorder]`'s defaults: `pre_s` + `post_s` and the second the cut needs.
const SPAN_S: f64 = 16.0;
const ROBOT_BYTES: usize = 8 << 20;

/// A joint sample at `t_s` of a robot moving smoothly, its twin pose and its deviation.
fn sample(t_s: f64) -> (JointSample, PoseReadout, Deviation) {
    let q: Vec<f64> = Q
        .iter()
        .enumerate()
        .map(|(i, q)| q + 0.3 * (t_s * (0.5 + 0.1 * i as f64)).sin())
        .collect();
    let sample = JointSample {
        stamp_s: None,
        seq: None,
        q_rad: JointAngles::from_slice(&q),
        measured: None,
        state: None,
    };
    let orientation = UnitQuaternion::from_euler_angles(0.1 + 0.2 * t_s.sin(), 0.2, 0.3);
    let twin = PoseReadout::from_position_quaternion(
        [-0.807 + 0.1 * t_s.sin(), 0.436, 0.42 + 0.1 * t_s.cos()],
        &orientation,
    );
    let measured = PoseReadout::from_position_quaternion(
        [-0.8075 + 0.1 * t_s.sin(), 0.436, 0.42 + 0.1 * t_s.cos()],
        &orientation,
    );
    let deviation = Deviation::between(&twin, &measured);
    (sample, twin, deviation)
}

/// A robot's joint and measured rings, full at 500 Hz, their log, and the next stamp.
fn full_rings() -> (RecordRing, RecordRing, std::sync::Arc<Spool>, f64) {
    // On a file, as the service keeps it (unnamed: nothing is left behind).
    let spool = Spool::in_dir(&std::env::temp_dir(), 1 << 30);
    let layout = JointRecord { joint_count: 6 };
    let mut joints = RecordRing::new(layout.stride(), SPAN_S, ROBOT_BYTES / 2, spool.clone());
    let mut measured = RecordRing::new(MEASURED_STRIDE, SPAN_S, ROBOT_BYTES / 4, spool.clone());
    let mut record = vec![0.0; layout.stride()];
    let count = 8010_u32;
    for i in 0..count {
        let t_s = f64::from(i) / RATE_HZ;
        let (sample, twin, deviation) = sample(t_s);
        layout.fill(&mut record, 1.7e9 + t_s, &sample, &twin);
        joints.push(&record);
        fill_measured(
            &mut record[..MEASURED_STRIDE],
            1.7e9 + t_s,
            &twin,
            &deviation,
        );
        measured.push(&record[..MEASURED_STRIDE]);
    }
    #[allow(clippy::print_stderr, reason = "the memory figure of README.md")]
    {
        eprintln!(
            "rings at 500 Hz over {SPAN_S} s: in memory joints {} B, measured {} B; the log {} B \
             for {count} joint and measured records ({:.1} B a pair, raw {} B)",
            joints.held_bytes(),
            measured.held_bytes(),
            spool.used_bytes(),
            spool.used_bytes() as f64 / f64::from(count),
            (layout.stride() + MEASURED_STRIDE) * 8,
        );
    }
    (joints, measured, spool, 1.7e9 + f64::from(count) / RATE_HZ)
}

fn per_sample(c: &mut Criterion) {
    let (sample, twin, deviation) = sample(1.0);
    let layout = JointRecord { joint_count: 6 };
    let (mut joints, mut measured, _spool, start_s) = full_rings();
    let mut record = vec![0.0; layout.stride()];
    let mut i = 0_u32;
    c.bench_function("recorder/joint_sample", |b| {
        b.iter(|| {
            i += 1;
            let stamp_s = start_s + f64::from(i) / RATE_HZ;
            layout.fill(&mut record, stamp_s, black_box(&sample), &twin);
            joints.push(black_box(&record));
        });
    });
    c.bench_function("recorder/joint_sample_and_measured_pose", |b| {
        b.iter(|| {
            i += 1;
            let stamp_s = start_s + f64::from(i) / RATE_HZ;
            layout.fill(&mut record, stamp_s, black_box(&sample), &twin);
            joints.push(black_box(&record));
            fill_measured(&mut record[..MEASURED_STRIDE], stamp_s, &twin, &deviation);
            measured.push(black_box(&record[..MEASURED_STRIDE]));
        });
    });
}

/// An incident of 15 s at 500 Hz, as the rings give it.
fn cut(joints: &RecordRing, measured: &RecordRing, end_s: f64) -> Incident {
    let (from_s, until_s) = (end_s - 15.0, end_s);
    let mut incident = Incident {
        robot: "site/cell-1/ur10e".to_owned(),
        model: "ur10e".to_owned(),
        calibration_source: "nominal".to_owned(),
        frame_id: "base".to_owned(),
        trigger: Trigger {
            kind: "alarm",
            stamp_s: end_s - 5.0,
            at: SystemTime::now(),
            event_json: "{\"kind\":\"alarm\"}".to_owned(),
        },
        from_s,
        until_s,
        joint_record: JointRecord { joint_count: 6 },
        joints: Vec::new(),
        measured: Vec::new(),
        efforts: Vec::new(),
        log: Vec::new(),
        drawn: None,
    };
    joints.copy_range(from_s, until_s, &mut incident.joints);
    measured.copy_range(from_s, until_s, &mut incident.measured);
    incident
}

fn incident_file(c: &mut Criterion) {
    let (joints, measured, _spool, end_s) = full_rings();
    let incident = cut(&joints, &measured, end_s);
    let mut group = c.benchmark_group("recorder");
    group.sample_size(20);
    group.bench_function("incident_cut_15s_500hz", |b| {
        b.iter(|| cut(black_box(&joints), &measured, end_s).joints.len());
    });
    group.bench_function("incident_file_15s_500hz/memory", |b| {
        b.iter(|| {
            let mut out = Cursor::new(Vec::with_capacity(4 << 20));
            write_mcap(&mut out, black_box(&incident)).expect("written");
            out.into_inner().len()
        });
    });
    let dir = tempfile::tempdir().expect("a temporary directory");
    let settings = StoreSettings {
        dir: dir.path().to_owned(),
        max_files: 1000,
        max_bytes: 1 << 40,
        robot_max_files: 1000,
        robot_max_bytes: 1 << 40,
    };
    group.bench_function("incident_file_15s_500hz/file_synced", |b| {
        b.iter(|| armtwin_recorder::store::write(&settings, black_box(&incident)));
    });
    group.finish();
}

criterion_group!(benches, per_sample, incident_file);
criterion_main!(benches);
