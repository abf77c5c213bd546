//! Decoding armtwin's JSON gateway messages: the entry points, and the checks that turn what
//! the one pass read (`slots`) into samples, naming what is wrong ([`super::WireError`]); the
//! usual shapes first go through the fast path (`fast`), which gives up on anything else. The
//! `state` object is read by `state`, a measured pose's orientation by `pose`.
//!
//! Must not know the network: bytes in, [`JointSample`] / [`MeasuredSample`] out.

use armtwin_core::kinematics::PoseReadout;
use armtwin_core::sample::{JointAngles, JointSample, MeasuredSample};

use super::joints::DecodedJoints;
use super::pose::{OrientationForm, POSE_KEYS, pose_of};
use super::slots::{
    Got, MessageSlots, PoseSlots, Schema, number, optional, read_message, wrong_type,
};
use super::state::joint_state;
use super::{Undecodable, WireError, fast};

/// The stamp (`t` or `time`) of a message, if it has a usable one, read without knowing what
/// kind of message it is (a message of an unknown robot is rejected at its own time).
#[must_use]
pub fn stamp_hint(payload: &[u8]) -> Option<f64> {
    match read_message(payload, Schema::Stamp) {
        Ok(slots) => slots.stamp_hint(),
        Err(undecodable) => undecodable.stamp_s,
    }
}

/// Decodes a joint message for an arm with `joint_count` joints.
///
/// Angles come back in radians whatever `unit` said; a `measured` object gets the joint
/// message's stamp. An invalid `measured` part is reported in
/// [`DecodedJoints::measured_error`], not as the message's error.
///
/// ```
/// use armtwin_codec::json::decode_joints;
/// let sample = decode_joints(br#"{"time": 2.5, "unit": "deg", "q1": 90, "q2": -45}"#, 2)?.sample;
/// assert_eq!(sample.stamp_s, Some(2.5));
/// assert!((sample.q_rad[0] - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
/// let error = decode_joints(br#"{"q": [0, "1.2"]}"#, 2).unwrap_err();
/// assert_eq!(error.kind(), "wrong_type");
/// assert_eq!(error.to_string(), "field 'q[1]': expected a number, got the string \"1.2\"");
/// # Ok::<(), armtwin_codec::json::WireError>(())
/// ```
pub fn decode_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, WireError> {
    read_joints(payload, joint_count).map_err(|undecodable| undecodable.error)
}

/// [`decode_joints`], and for a refused message the stamp it offers, from the same pass.
///
/// ```
/// use armtwin_codec::json::read_joints;
/// let refused = read_joints(br#"{"t": 3.5, "q": [0, 0, 0]}"#, 2).unwrap_err();
/// assert_eq!(refused.error.kind(), "joint_count");
/// assert_eq!(refused.stamp_s, Some(3.5));
/// assert_eq!(read_joints(b"{\"t\": 3.5,", 2).unwrap_err().stamp_s, None);
/// ```
pub fn read_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, Undecodable> {
    match fast::joints(payload, joint_count) {
        Some(decoded) => Ok(decoded),
        None => general_joints(payload, joint_count),
    }
}

/// [`read_joints`] for any message, naming what is wrong with an invalid one.
pub fn general_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, Undecodable> {
    let slots = read_message(payload, Schema::Joints { joint_count })?;
    let stamp_s = slots.stamp_hint();
    slots
        .into_joints(joint_count)
        .map_err(|error| Undecodable { error, stamp_s })
}

/// Decodes a measured-pose message: position (m) and exactly one orientation form, the
/// quaternion normalised (within 5 % of unit norm) and canonicalised to `qw ≥ 0`.
pub fn decode_measured(payload: &[u8]) -> Result<MeasuredSample, WireError> {
    read_measured(payload).map_err(|undecodable| undecodable.error)
}

/// [`decode_measured`], and for a refused message the stamp it offers, from the same pass.
pub fn read_measured(payload: &[u8]) -> Result<MeasuredSample, Undecodable> {
    match fast::measured(payload) {
        Some(measured) => Ok(measured),
        None => general_measured(payload),
    }
}

/// [`read_measured`] for any message, naming what is wrong with an invalid one.
pub fn general_measured(payload: &[u8]) -> Result<MeasuredSample, Undecodable> {
    let slots = read_message(payload, Schema::Measured)?;
    let stamp_s = slots.stamp_hint();
    slots
        .into_measured()
        .map_err(|error| Undecodable { error, stamp_s })
}

/// The first of `form`'s fields present in `pose`, as an index into [`POSE_KEYS`].
fn first_present(form: OrientationForm, pose: &PoseSlots) -> Option<usize> {
    form.slots().find(|&index| pose[index].is_some())
}

/// Position and exactly one orientation form, from a measured pose object.
fn pose_readout(pose: &PoseSlots, prefix: &str) -> Result<PoseReadout, WireError> {
    let required = |index: usize| {
        let field = || format!("{prefix}{}", POSE_KEYS[index]);
        match &pose[index] {
            Some(got) => number(got, field),
            None => Err(WireError::MissingField { field: field() }),
        }
    };
    let position_m = [required(0)?, required(1)?, required(2)?];
    let present = || {
        OrientationForm::ALL
            .into_iter()
            .filter_map(|form| first_present(form, pose).map(|index| (form, index)))
    };
    let mut forms = present();
    let (Some((form, _)), None) = (forms.next(), forms.next()) else {
        return Err(WireError::OrientationForms {
            found: present()
                .map(|(_, index)| format!("{prefix}{}", POSE_KEYS[index]))
                .collect(),
        });
    };
    let mut values = [0.0; 4];
    for (value, index) in values.iter_mut().zip(form.slots()) {
        *value = required(index)?;
    }
    pose_of(prefix, position_m, form, values)
}

/// The checks on what the pass read.
impl MessageSlots {
    /// `t` or `time` (not both), a finite number, or `None`.
    fn stamp(&self) -> Result<Option<f64>, WireError> {
        match (optional(self.t.as_ref()), optional(self.time.as_ref())) {
            (Some(_), Some(_)) => Err(WireError::AmbiguousFields {
                first: "t".to_owned(),
                second: "time".to_owned(),
            }),
            (Some(got), None) => number(got, || "t".to_owned()).map(Some),
            (None, Some(got)) => number(got, || "time".to_owned()).map(Some),
            (None, None) => Ok(None),
        }
    }

    /// The stamp a refused message offers: `t` if present (a `null` or any non-number gives
    fn into_joints(self, joint_count: usize) -> Result<DecodedJoints, WireError> {
        let stamp_s = self.stamp()?;
        let seq = match optional(self.seq.as_ref()) {
            None => None,
            Some(got) => Some(
                match got {
                    Got::Number(number) => number.to_u64(),
                    _ => None,
                }
                .ok_or_else(|| wrong_type("seq".to_owned(), "a non-negative integer", got))?,
            ),
        };
        let degrees = match optional(self.unit.as_ref()) {
            None => false,
            Some(Got::String { head, .. }) if head == "rad" => false,
            Some(Got::String { head, .. }) if head == "deg" => true,
            Some(Got::String { head, .. }) => {
                return Err(WireError::Unit {
                    got: head.to_string(),
                });
            }
            Some(other) => return Err(wrong_type("unit".to_owned(), "a string", other)),
        };
        let (measured, measured_error) = match optional(self.measured.as_ref()) {
            None => (None, None),
            Some(Got::Object) => match pose_readout(&self.measured_pose, "measured.") {
                Ok(pose) => (Some(pose), None),
                Err(error) => (None, Some(error)),
            },
            Some(other) => (
                None,
                Some(wrong_type("measured".to_owned(), "an object", other)),
            ),
        };
        let (state, state_error) = match self.state.as_ref().filter(|value| !value.is_null()) {
            None => (None, None),
            Some(value) => match joint_state(value, joint_count) {
                Ok(state) => (
                    Some(Box::new(state)).filter(|state| !state.is_empty()),
                    None,
                ),
                Err(error) => (None, Some(error)),
            },
        };
        let mut q_rad = self.joint_angles(joint_count)?;
        if degrees {
            for angle in &mut q_rad {
                *angle = angle.to_radians();
            }
        }
        Ok(DecodedJoints {
            sample: JointSample {
                stamp_s,
                seq,
                q_rad: JointAngles::from_vec(q_rad),
                measured,
                state,
            },
            measured_error,
            state_error,
        })
    }

    /// Exactly `joint_count` angles, from the `q` array or from `q1..qn`, in message units.
    fn joint_angles(self, joint_count: usize) -> Result<Vec<f64>, WireError> {
        let flat = self.flat;
        if let Some(q) = &self.q {
            if let Some(lowest) = flat.lowest {
                return Err(WireError::AmbiguousFields {
                    first: "q".to_owned(),
                    second: format!("q{lowest}"),
                });
            }
            if *q != Got::Array {
                return Err(wrong_type("q".to_owned(), "an array", q));
            }
            let angles = self.angles;
            if angles.count != joint_count {
                return Err(WireError::JointCount {
                    field: "q".to_owned(),
                    expected: joint_count,
                    got: angles.count,
                });
            }
            if let Some((index, got)) = &angles.first_non_number {
                return Err(wrong_type(format!("q[{index}]"), "a number", got));
            }
            return Ok(angles.values);
        }
        if flat.count == 0 {
            return Err(WireError::MissingField {
                field: "q".to_owned(),
            });
        }
        if flat.count != joint_count {
            return Err(WireError::JointCount {
                field: format!("q1..q{joint_count}"),
                expected: joint_count,
                got: flat.count,
            });
        }
        (1..=joint_count)
            .map(|joint| {
                let field = || format!("q{joint}");
                match flat.values.get(joint - 1) {
                    Some(Some(got)) => number(got, field),
                    // As many `q<n>` fields as joints, so one beyond `q{joint_count}` takes its place.
                    _ => Err(WireError::MissingField { field: field() }),
                }
            })
            .collect()
    }

    fn into_measured(self) -> Result<MeasuredSample, WireError> {
        Ok(MeasuredSample {
            stamp_s: self.stamp()?,
            pose: pose_readout(&self.pose, "")?,
        })
    }
}
