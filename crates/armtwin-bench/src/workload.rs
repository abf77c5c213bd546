//! The messages of the load: joint samples and measured poses shaped exactly like the contract's
//! (`docs/protocol/messages.md`), as a gateway streaming an RTDE-like robot sends them.
//!
//! Owns the payloads, JSON text or Zenoh-serialized bytes; knows nothing of the network. The joint angles cycle through a few
//! fixed configurations of a `ur10e`, and each measured pose is the nominal FK of its joint sample
//! moved by half a millimetre: a realistic deviation that raises no alarm, so armtwin's outputs
//! are exactly one pose and one deviation per sample plus its periodic metrics.

use std::fmt::Write as _;

use armtwin_core::kinematics::KinematicsError;
use armtwin_core::model::{ModelError, RobotModel};
use thiserror::Error;

/// Joint configurations the samples cycle through.
const CONFIGURATIONS: usize = 16;

/// Measured minus nominal FK position (m): 0.54 mm, below armtwin's default 5 mm alarm.
const MEASURED_OFFSET_M: [f64; 3] = [0.0004, -0.0002, 0.0003];

/// Why the payloads could not be built (the catalog or FK failed: a bug, not input).
#[derive(Debug, Error)]
pub enum WorkloadError {
    /// The model is not in the catalog.
    #[error("model: {0}")]
    Model(#[from] ModelError),
    /// FK refused a configuration.
    #[error("forward kinematics: {0}")]
    Kinematics(#[from] KinematicsError),
}

/// Pre-rendered parts of each configuration's messages.
#[derive(Debug, Clone)]
struct Configuration {
    /// `[q1,…,q6]`.
    joints_json: String,
    /// `"x":…,"qw":…` (no braces, no stamp).
    measured_fields: String,
    /// The angles (rad).
    q_rad: Vec<f64>,
    /// The measured pose: `x, y, z` (m), `qx, qy, qz, qw`.
    measured_values: [f64; 7],
}

/// The load's payloads.
#[derive(Debug, Clone)]
pub struct Workload {
    configurations: Vec<Configuration>,
}

impl Workload {
    /// The payloads of a nominal `ur10e`.
    pub fn ur10e() -> Result<Self, WorkloadError> {
        let model = RobotModel::nominal("ur10e")?;
        let configurations = (0..CONFIGURATIONS)
            .map(|index| {
                // Spread over the joint ranges, deterministic.
                let q_rad: Vec<f64> = (0..6)
                    .map(|joint: i32| 2.0 * (1.3 * index as f64 + f64::from(joint)).sin())
                    .collect();
                let pose = model.pose(&q_rad).map(|pose| pose.readout())?;
                let joints_json = format!(
                    "[{}]",
                    q_rad
                        .iter()
                        .map(f64::to_string)
                        .collect::<Vec<_>>()
                        .join(",")
                );
                let [x, y, z] = pose.position_m;
                let [dx, dy, dz] = MEASURED_OFFSET_M;
                let [qx, qy, qz, qw] = pose.quaternion_xyzw;
                let measured_fields = format!(
                    r#""x":{},"y":{},"z":{},"qx":{qx},"qy":{qy},"qz":{qz},"qw":{qw}"#,
                    x + dx,
                    y + dy,
                    z + dz
                );
                Ok(Configuration {
                    joints_json,
                    measured_fields,
                    measured_values: [x + dx, y + dy, z + dz, qx, qy, qz, qw],
                    q_rad,
                })
            })
            .collect::<Result<_, KinematicsError>>()?;
        Ok(Self { configurations })
    }

    fn configuration(&self, sample: u64) -> &Configuration {
        &self.configurations[(sample % self.configurations.len() as u64) as usize]
    }

    /// The joint message of a robot's `sample`-th sample: `{"t":…,"q":[…]}`. No gateway `seq`:
    /// one load process follows another against the same system under test, and a `seq` that
    /// started again would be refused.
    #[must_use]
    pub fn joints(&self, sample: u64, stamp_s: f64) -> String {
        let mut text = String::with_capacity(160);
        // Writing to a `String` cannot fail.
        let _ = write!(
            text,
            r#"{{"t":{stamp_s},"q":{}}}"#,
            self.configuration(sample).joints_json
        );
        text
    }

    /// The joint message with the same sample's measured pose embedded, as an RTDE gateway
    /// sends both from one packet: `{"t":…,"q":[…],"measured":{"x":…,…,"qw":…}}`.
    #[must_use]
    pub fn joints_with_measured(&self, sample: u64, stamp_s: f64) -> String {
        let configuration = self.configuration(sample);
        let mut text = String::with_capacity(320);
        let _ = write!(
            text,
            r#"{{"t":{stamp_s},"q":{},"measured":{{{}}}}}"#,
            configuration.joints_json, configuration.measured_fields
        );
        text
    }

    /// The joint message in Zenoh's serialization (`armtwin/joints/v1`):
    /// `(t, q, seq, measured)`, `measured` the same sample's pose when `embedded`, else empty.
    /// The schema's `seq` is required: the caller gives one that keeps increasing across load
    /// processes.
    #[must_use]
    pub fn joints_zser(&self, sample: u64, stamp_s: f64, seq: u64, embedded: bool) -> Vec<u8> {
        let configuration = self.configuration(sample);
        armtwin_codec::zser::joints_bytes(
            stamp_s,
            &configuration.q_rad,
            seq,
            embedded.then_some(&configuration.measured_values),
        )
    }

    /// The measured pose in Zenoh's serialization (`armtwin/pose/v1`): `(t, pose)`.
    #[must_use]
    pub fn measured_zser(&self, sample: u64, stamp_s: f64) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(8 + 1 + 8 * 7);
        bytes.extend_from_slice(&stamp_s.to_le_bytes());
        push_f64s(&mut bytes, &self.configuration(sample).measured_values);
        bytes
    }

    /// The measured pose that goes with the same sample: `{"t":…,"x":…,…,"qw":…}`.
    #[must_use]
    pub fn measured(&self, sample: u64, stamp_s: f64) -> String {
        let mut text = String::with_capacity(200);
        let _ = write!(
            text,
            r#"{{"t":{stamp_s},{}}}"#,
            self.configuration(sample).measured_fields
        );
        text
    }
}

/// A sequence of fewer than 128 values: a one-byte LEB128 length, then the values.
fn push_f64s(bytes: &mut Vec<u8>, values: &[f64]) {
    bytes.push(values.len() as u8);
    for value in values {
        bytes.extend_from_slice(&value.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use armtwin_codec::{json, zser};

    #[test]
    fn messages_decode_as_the_contract_says() {
        let workload = Workload::ur10e().expect("ur10e");
        for sample in 0..CONFIGURATIONS as u64 {
            let joints = json::decode_joints(workload.joints(sample, 1.25).as_bytes(), 6)
                .expect("joint message");
            assert_eq!(joints.sample.stamp_s, Some(1.25));
            assert_eq!(joints.sample.seq, None);
            let model = RobotModel::nominal("ur10e").expect("ur10e");
            model
                .check_joints(&joints.sample.q_rad)
                .expect("within limits");
            let measured = json::decode_measured(workload.measured(sample, 1.25).as_bytes())
                .expect("measured message");
            assert_eq!(measured.stamp_s, Some(1.25));
            let twin = model.pose(&joints.sample.q_rad).expect("pose").readout();
            let distance_m = (0..3)
                .map(|axis| (twin.position_m[axis] - measured.pose.position_m[axis]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!((distance_m - 0.000_538_5).abs() < 1e-6, "{distance_m}");
            let embedded =
                json::decode_joints(workload.joints_with_measured(sample, 1.25).as_bytes(), 6)
                    .expect("joint message with its measured pose");
            assert_eq!(embedded.sample.q_rad, joints.sample.q_rad);
            assert_eq!(embedded.sample.measured, Some(measured.pose));
            // The binary messages: zenoh-ext's bytes, and the same samples once decoded.
            let configuration = workload.configuration(sample);
            let binary = workload.joints_zser(sample, 1.25, 9, true);
            let oracle = zenoh_ext::z_serialize(&(
                1.25,
                configuration.q_rad.clone(),
                9_u64,
                configuration.measured_values.to_vec(),
            ));
            assert_eq!(binary, oracle.to_bytes().as_ref());
            let decoded = zser::read_joints(&binary, 6).expect("binary joint message");
            assert_eq!(decoded.sample.q_rad, joints.sample.q_rad);
            assert_eq!(decoded.sample.measured, Some(measured.pose));
            let decoded = zser::read_joints(&workload.joints_zser(sample, 1.25, 9, false), 6)
                .expect("binary joint message without measured pose");
            assert_eq!(decoded.sample.measured, None);
            let binary = zser::read_measured(&workload.measured_zser(sample, 1.25))
                .expect("binary measured pose");
            assert_eq!(binary.pose, measured.pose);
        }
    }
}
