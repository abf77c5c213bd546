//! The in-process ingest benchmarks' load, shared by `benches/ingest.rs` and
//! `examples/ingest_latency.rs`: one robot's joint and measured payloads as
//! `armtwin-bench load` sends them, the pipeline as `armtwin-bench run` configures the service,
//! and a sink that encodes every output as `armtwin serve` does before its `put`.
#![allow(
    clippy::expect_used,
    reason = "the fixtures are the checkout's own constants and example files"
)]

use std::hint::black_box;

use armtwin_codec::{PoseFields, json, zser};
use armtwin_core::kinematics::{OutputFrame, PoseReadout};
use armtwin_core::metrics::Deviation;
use armtwin_core::pipeline::{
    Event, MeasuredStream, MetricsReadout, Pipeline, Robot, RobotDirectory, Sink,
};
use armtwin_mesh::ingest::{self, Codec};

use crate::fleet::{parsed_service_config, robot_id};
use crate::net;
use crate::workload::Workload;

/// Samples rendered ahead; a run longer than this starts again on a fresh pipeline (untimed).
pub const RENDERED: usize = 4096;

/// Encodes every output as `armtwin serve` does before its `put` (poses and deviations in JSON
/// by default, or binary), and keeps only counts.
#[derive(Default)]
pub struct Encode {
    /// Poses and deviations in Zenoh's serialization rather than JSON.
    pub binary: bool,
    /// Bytes encoded.
    pub bytes: usize,
    /// Poses and deviations encoded.
    pub outputs: u64,
    /// Events encoded.
    pub events: u64,
}

impl Sink for Encode {
    fn pose(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        seq: u64,
        frame: OutputFrame,
        pose: &PoseReadout,
    ) {
        let fields = PoseFields::from(pose);
        self.outputs += 1;
        self.bytes += if self.binary {
            black_box(zser::twin_pose_bytes(stamp_s, seq, &fields)).len()
        } else {
            black_box(json::pose_json_bytes(
                robot.id(),
                stamp_s,
                seq,
                frame.as_str(),
                &fields,
            ))
            .len()
        };
    }

    fn deviation(&mut self, robot: &Robot, stamp_s: f64, _: &PoseReadout, deviation: &Deviation) {
        self.outputs += 1;
        self.bytes += if self.binary {
            black_box(zser::deviation_bytes(stamp_s, deviation)).len()
        } else {
            black_box(json::deviation_json_bytes(robot.id(), stamp_s, deviation)).len()
        };
    }

    fn event(&mut self, event: &Event<'_>) {
        self.events += 1;
        self.bytes += black_box(json::to_json_bytes(&json::EventMessage::new(event))).len();
    }

    fn metrics(&mut self, _robot: &Robot, readout: &MetricsReadout) {
        self.bytes += black_box(json::MetricsMessage::new(readout).to_json_bytes()).len();
    }
}

/// A robot's id and its input keys, as `armtwin-bench load` publishes them.
pub struct RobotKeys {
    /// The robot's id.
    pub id: String,
    /// Its joint messages' key.
    pub joints: String,
    /// Its measured poses' key.
    pub measured: String,
}

impl RobotKeys {
    /// Robot `index` of the benchmark's fleet.
    #[must_use]
    pub fn of(index: usize) -> Self {
        let id = robot_id(index);
        Self {
            joints: net::key(net::JOINTS, &id),
            measured: net::key(net::MEASURED, &id),
            id,
        }
    }
}

/// One sample of `robot` into `pipeline` as the service feeds it: its joint message, then its
/// measured pose, decoded with `codecs` (joints, measured), `stamp_s` their arrival time.
pub fn feed(
    pipeline: &mut Pipeline,
    (robot, keys): (&Robot, &RobotKeys),
    (joint_codec, measured_codec): (Codec, Codec),
    (stamp_s, joints, measured): (f64, &[u8], &[u8]),
    sink: &mut impl Sink,
) {
    ingest::joint_message(
        pipeline,
        robot,
        &keys.joints,
        joint_codec,
        joints,
        || stamp_s,
        sink,
    );
    ingest::measured_message(
        pipeline,
        robot,
        &keys.measured,
        MeasuredStream::Robot,
        measured_codec,
        measured,
        || stamp_s,
        sink,
    );
}

/// One robot's load: joint and measured payloads of `RENDERED` samples at 100 Hz.
pub struct Load {
    /// The robot's id.
    pub robot: String,
    keys: RobotKeys,
    /// Stamp (s), joint payload and measured payload of each sample.
    pub samples: Vec<(f64, String, String)>,
}

impl Load {
    /// Samples `first..first + RENDERED`: their stamps continue those of the samples before, so
    /// one pipeline can take load after load.
    #[must_use]
    pub fn starting_at(first: u64) -> Self {
        let workload = Workload::ur10e().expect("the ur10e's payloads");
        let robot = robot_id(0);
        let samples = (first..first + RENDERED as u64)
            .map(|sample| {
                let stamp_s = 1000.0 + sample as f64 * 0.01;
                (
                    stamp_s,
                    workload.joints(sample, stamp_s),
                    workload.measured(sample, stamp_s),
                )
            })
            .collect();
        Self {
            keys: RobotKeys::of(0),
            robot,
            samples,
        }
    }

    /// A pipeline and its robots, configured as `armtwin-bench run` configures the service for
    /// one robot.
    #[must_use]
    pub fn pipeline() -> Twin {
        Twin::of(1)
    }
}

/// A pipeline and the directory its robots are resolved in, as the service holds them.
pub struct Twin {
    /// Who may be tracked.
    pub robots: RobotDirectory,
    /// The twins.
    pub pipeline: Pipeline,
}

impl Twin {
    /// Configured as `armtwin-bench run` configures the service for `robots` robots.
    #[must_use]
    pub fn of(robots: usize) -> Self {
        let config = parsed_service_config(robots).expect("the benchmark's configuration");
        Self {
            robots: RobotDirectory::new(config.default_robot, config.robots),
            pipeline: Pipeline::new(config.pipeline),
        }
    }
}

impl Load {
    /// Sample `index`'s joint message into `twin`, its robot resolved by id as the service
    /// resolves it.
    pub fn joints(&self, twin: &mut Twin, index: usize, sink: &mut impl Sink) {
        let (stamp_s, joints, _) = &self.samples[index];
        let robot = twin.robots.find(&self.robot).expect("a configured robot");
        ingest::joint_message(
            &mut twin.pipeline,
            robot,
            &self.keys.joints,
            Codec::Json,
            joints.as_bytes(),
            || *stamp_s,
            sink,
        );
    }

    /// Sample `index`'s measured pose into `twin`.
    pub fn measured(&self, twin: &mut Twin, index: usize, sink: &mut impl Sink) {
        let (stamp_s, _, measured) = &self.samples[index];
        let robot = twin.robots.find(&self.robot).expect("a configured robot");
        ingest::measured_message(
            &mut twin.pipeline,
            robot,
            &self.keys.measured,
            MeasuredStream::Robot,
            Codec::Json,
            measured.as_bytes(),
            || *stamp_s,
            sink,
        );
    }
}
