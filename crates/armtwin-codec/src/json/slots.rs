//! The JSON layer of the general decoder: one pass of `serde_json`'s parser over a message into
//! fixed slots. Fields a message does not use are skipped unparsed (their numbers never
//! converted, so they may hold anything, even `1e400`); kept fields record what they held, and
//! the checks on the slots (`decode`) name the problem afterwards. Checks here only what the
//! parser sees: size, UTF-8, JSON syntax, an object at the top, numbers within f64, repeated
//! fields.

use std::borrow::Cow;
use std::collections::BTreeSet;
use std::fmt::{self, Write as _};

use serde::de::{self, DeserializeSeed, Deserializer, IgnoredAny, MapAccess, SeqAccess, Visitor};
use serde_json::{Number, Value};

use super::pose::POSE_KEYS;
use super::{MAX_PAYLOAD_BYTES, Undecodable, WireError};

/// The `n` in a flat joint field `qn` (`q1`, `q2`, …; no sign, no leading zero).
#[must_use]
pub fn joint_index(key: &str) -> Option<usize> {
    let digits = key.strip_prefix('q')?;
    if digits.is_empty() || digits.starts_with('0') || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// Which fields of a message's top level are kept.
#[derive(Debug, Clone, Copy)]
pub(super) enum Schema {
    /// A joint message: stamp, `seq`, `unit`, `q` or `q1..qN`, and a `measured` pose.
    Joints {
        /// The arm's joint count: how many angles are kept.
        joint_count: usize,
    },
    /// A measured-pose message: stamp and pose fields.
    Measured,
    /// Only the stamp.
    Stamp,
}

/// A top-level field of a message.
#[derive(Debug, Clone, Copy)]
enum MessageKey {
    T,
    Time,
    Seq,
    Unit,
    Q,
    /// `q<n>`.
    Joint(usize),
    Measured,
    /// `state`: the joint state beside the angles.
    State,
    /// A pose field of a measured-pose message, as an index into [`POSE_KEYS`].
    Pose(usize),
    /// A field the message does not use.
    Other,
}

impl MessageKey {
    fn of(schema: Schema, key: &str) -> Self {
        match (schema, key) {
            (_, "t") => Self::T,
            (_, "time") => Self::Time,
            (Schema::Joints { .. }, "seq") => Self::Seq,
            (Schema::Joints { .. }, "unit") => Self::Unit,
            (Schema::Joints { .. }, "q") => Self::Q,
            (Schema::Joints { .. }, "measured") => Self::Measured,
            (Schema::Joints { .. }, "state") => Self::State,
            (Schema::Joints { .. }, other) => joint_index(other).map_or(Self::Other, Self::Joint),
            (Schema::Measured, other) => pose_key(other).map_or(Self::Other, Self::Pose),
            (Schema::Stamp, _) => Self::Other,
        }
    }
}

fn pose_key(key: &str) -> Option<usize> {
    POSE_KEYS.iter().position(|pose_key| *pose_key == key)
}

/// A JSON number as the parser gave it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Num {
    Unsigned(u64),
    Signed(i64),
    Float(f64),
}

impl Num {
    pub(super) fn to_f64(self) -> f64 {
        match self {
            Self::Unsigned(value) => value as f64,
            Self::Signed(value) => value as f64,
            Self::Float(value) => value,
        }
    }

    pub(super) fn to_u64(self) -> Option<u64> {
        match self {
            Self::Unsigned(value) => Some(value),
            Self::Signed(value) => u64::try_from(value).ok(),
            Self::Float(_) => None,
        }
    }
}

/// What a kept field held: enough for its checks and for naming it in an error.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Got {
    Null,
    Boolean,
    Number(Num),
    /// A string: its first 40 characters and whether there were more, or for `unit` the whole
    /// text (a unit error quotes it whole).
    String {
        head: Cow<'static, str>,
        cut: bool,
    },
    Array,
    Object,
}

impl Got {
    fn json_type(&self) -> &'static str {
        match self {
            Self::Null => "null",
            Self::Boolean => "a boolean",
            Self::Number(_) => "a number",
            Self::String { .. } => "a string",
            Self::Array => "an array",
            Self::Object => "an object",
        }
    }

    /// How an error message names it: the number or the text itself (cut short), so a log or a
    /// report shows what the gateway sent.
    fn describe(&self) -> String {
        match self {
            Self::Number(number) => {
                let number = match *number {
                    Num::Unsigned(value) => Number::from(value),
                    Num::Signed(value) => Number::from(value),
                    // The parser yields only finite numbers.
                    Num::Float(value) => match Number::from_f64(value) {
                        Some(number) => number,
                        None => return Self::Null.json_type().to_owned(),
                    },
                };
                format!("the number {number}")
            }
            Self::String { head, cut: false } => format!("the string {head:?}"),
            Self::String { head, cut: true } => format!("the string {head:?}…"),
            other => other.json_type().to_owned(),
        }
    }
}

/// The value of an optional field; `null` counts as absent.
pub(super) fn optional(slot: Option<&Got>) -> Option<&Got> {
    slot.filter(|got| **got != Got::Null)
}

/// A finite JSON number (the parser already rejected overflowing ones); strings are not coerced.
pub(super) fn number(got: &Got, field: impl FnOnce() -> String) -> Result<f64, WireError> {
    match got {
        Got::Number(number) => Ok(number.to_f64()),
        other => Err(wrong_type(field(), "a number", other)),
    }
}

pub(super) fn wrong_type(field: String, expected: &'static str, got: &Got) -> WireError {
    WireError::WrongType {
        field,
        expected,
        got: got.describe(),
    }
}

/// The `q` array: every item counted, the first `joint_count` numbers kept and the first item
/// that is not a number remembered.
#[derive(Debug, Default)]
pub(super) struct AngleArray {
    pub(super) count: usize,
    pub(super) values: Vec<f64>,
    pub(super) first_non_number: Option<(usize, Got)>,
}

/// The flat `q1..qN` fields.
#[derive(Debug, Default)]
pub(super) struct FlatAngles {
    /// How many different `q<n>` fields there are.
    pub(super) count: usize,
    /// The lowest `n`, for naming the field that clashes with `q`.
    pub(super) lowest: Option<usize>,
    /// `q1..q{joint_count}`, allocated at the first of them.
    pub(super) values: Vec<Option<Got>>,
    /// The `n` beyond the arm's joints seen so far, only to notice a repeated field.
    pub(super) beyond: BTreeSet<usize>,
    /// Where the value of a field beyond the arm's joints is read.
    pub(super) scratch: Option<Got>,
}

impl FlatAngles {
    /// The slot of `q<n>`, and whether the field was seen before.
    fn slot(&mut self, n: usize, joint_count: usize) -> (&mut Option<Got>, bool) {
        self.lowest = Some(self.lowest.map_or(n, |lowest| lowest.min(n)));
        let repeated = if n <= joint_count {
            if self.values.is_empty() {
                self.values.resize_with(joint_count, || None);
            }
            self.values[n - 1].is_some()
        } else {
            !self.beyond.insert(n)
        };
        if !repeated {
            self.count += 1;
        }
        let slot = if n <= joint_count {
            &mut self.values[n - 1]
        } else {
            &mut self.scratch
        };
        (slot, repeated)
    }
}

/// The fields of a measured pose, in [`POSE_KEYS`] order.
pub(super) type PoseSlots = [Option<Got>; 13];

/// What the pass read from a message.
#[derive(Debug, Default)]
pub(super) struct MessageSlots {
    pub(super) t: Option<Got>,
    pub(super) time: Option<Got>,
    pub(super) seq: Option<Got>,
    pub(super) unit: Option<Got>,
    pub(super) q: Option<Got>,
    /// The items of `q` when it is an array.
    pub(super) angles: AngleArray,
    pub(super) flat: FlatAngles,
    pub(super) measured: Option<Got>,
    /// The fields of `measured` when it is an object.
    pub(super) measured_pose: PoseSlots,
    /// The pose fields of a measured-pose message.
    pub(super) pose: PoseSlots,
    /// `state`, read whole: it is rarer than the angles, and read again field by field.
    pub(super) state: Option<Value>,
}

impl MessageSlots {
    /// none), else `time`.
    pub(super) fn stamp_hint(&self) -> Option<f64> {
        match self.t.as_ref().or(self.time.as_ref()) {
            Some(Got::Number(number)) => Some(number.to_f64()).filter(|t| t.is_finite()),
            _ => None,
        }
    }
}

/// Where a value sits in the message (`measured.qx`, `q[2]`), as a chain on the parser's stack:
/// written out only for an error.
#[derive(Debug, Clone, Copy)]
struct Path<'a> {
    parent: Option<&'a Path<'a>>,
    segment: Segment<'a>,
}

#[derive(Debug, Clone, Copy)]
enum Segment<'a> {
    Key(&'a str),
    /// `q<n>`.
    Joint(usize),
    Index(usize),
}

impl Path<'_> {
    fn render(&self) -> String {
        let mut text = self.parent.map(Path::render).unwrap_or_default();
        let separator = if text.is_empty() { "" } else { "." };
        // Writing to a `String` cannot fail.
        let _ = match self.segment {
            Segment::Key(key) => write!(text, "{separator}{key}"),
            Segment::Joint(n) => write!(text, "{separator}q{n}"),
            Segment::Index(index) => write!(text, "[{index}]"),
        };
        text
    }
}

/// What the pass noticed besides the values: the first repeated field, and the kept value it
/// was reading when the parser failed.
#[derive(Debug, Default)]
struct Trace {
    repeated: Option<String>,
    failed_at: Option<String>,
}

impl Trace {
    fn note_repeated(&mut self, path: &Path<'_>) {
        if self.repeated.is_none() {
            self.repeated = Some(path.render());
        }
    }

    /// Passes `result` on, noting `path` if the parser failed inside it (the innermost value
    /// notes first).
    fn located<T, E>(&mut self, result: Result<T, E>, path: &Path<'_>) -> Result<T, E> {
        if result.is_err() && self.failed_at.is_none() {
            self.failed_at = Some(path.render());
        }
        result
    }

    fn into_error(self, error: &serde_json::Error) -> WireError {
        if let Some(field) = self.repeated {
            return WireError::DuplicateField { field };
        }
        // serde_json reports a number beyond f64 only through its message.
        let out_of_range = error.classify() == serde_json::error::Category::Syntax
            && error.to_string().starts_with("number out of range");
        match self.failed_at {
            Some(field) if out_of_range => WireError::NonFinite { field },
            _ => WireError::NotJson {
                detail: error.to_string(),
            },
        }
    }
}

/// Checks size and encoding, then reads the message with `schema` in one pass.
pub(super) fn read_message(payload: &[u8], schema: Schema) -> Result<MessageSlots, Undecodable> {
    let refused = |error| Undecodable {
        error,
        stamp_s: None,
    };
    if payload.len() > MAX_PAYLOAD_BYTES {
        return Err(refused(WireError::TooLarge {
            bytes: payload.len(),
            limit: MAX_PAYLOAD_BYTES,
        }));
    }
    let text = std::str::from_utf8(payload).map_err(|error| {
        refused(WireError::NotUtf8 {
            valid_up_to: error.valid_up_to(),
        })
    })?;
    let mut slots = MessageSlots::default();
    let mut trace = Trace::default();
    let mut deserializer = serde_json::Deserializer::from_str(text);
    let parsed = Probe {
        into: Target::Message {
            schema,
            slots: &mut slots,
        },
        path: None,
        trace: &mut trace,
    }
    .deserialize(&mut deserializer)
    .and_then(|got| deserializer.end().map(|()| got));
    match parsed {
        Err(error) => Err(refused(trace.into_error(&error))),
        // A repeated field is reported even when the rest of the message is well formed; the
        // stamp is then the last `t` or `time`, as the last of a JSON object's repeated keys
        // usually counts.
        Ok(_) if trace.repeated.is_some() => Err(Undecodable {
            error: WireError::DuplicateField {
                field: trace.repeated.unwrap_or_default(),
            },
            stamp_s: slots.stamp_hint(),
        }),
        Ok(Got::Object) => Ok(slots),
        Ok(other) => Err(refused(WireError::NotObject {
            got: other.json_type(),
        })),
    }
}

/// Where the value being read goes.
enum Target<'a> {
    /// Inside a kept field: only what the value is (its contents are still checked: numbers
    /// within f64, no repeated key).
    Value,
    /// `unit`: a string is kept whole.
    WholeString,
    /// `q`: the items of an array.
    Angles {
        angles: &'a mut AngleArray,
        joint_count: usize,
    },
    /// A measured pose object embedded in a joint message (its own `t`/`time` skipped).
    Pose(&'a mut PoseSlots),
    /// A whole message.
    Message {
        schema: Schema,
        slots: &'a mut MessageSlots,
    },
}

/// Reads one JSON value into `into`, returning what it was.
struct Probe<'a> {
    into: Target<'a>,
    /// Where the value sits; `None` for the message itself.
    path: Option<&'a Path<'a>>,
    trace: &'a mut Trace,
}

impl<'de> DeserializeSeed<'de> for Probe<'_> {
    type Value = Got;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<Got, D::Error> {
        deserializer.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Probe<'_> {
    type Value = Got;

    fn expecting(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        formatter.write_str("a JSON value")
    }

    fn visit_bool<E: de::Error>(self, _: bool) -> Result<Got, E> {
        Ok(Got::Boolean)
    }

    fn visit_i64<E: de::Error>(self, value: i64) -> Result<Got, E> {
        Ok(Got::Number(Num::Signed(value)))
    }

    fn visit_u64<E: de::Error>(self, value: u64) -> Result<Got, E> {
        Ok(Got::Number(Num::Unsigned(value)))
    }

    fn visit_f64<E: de::Error>(self, value: f64) -> Result<Got, E> {
        // serde_json never yields a non-finite number; if another parser did, it reads as null.
        Ok(if value.is_finite() {
            Got::Number(Num::Float(value))
        } else {
            Got::Null
        })
    }

    fn visit_str<E: de::Error>(self, text: &str) -> Result<Got, E> {
        const KEPT_CHARS: usize = 40;
        let head = match self.into {
            Target::WholeString => match text {
                "rad" => Cow::Borrowed("rad"),
                "deg" => Cow::Borrowed("deg"),
                other => Cow::Owned(other.to_owned()),
            },
            _ => Cow::Owned(text.chars().take(KEPT_CHARS).collect()),
        };
        let cut =
            !matches!(self.into, Target::WholeString) && text.chars().nth(KEPT_CHARS).is_some();
        Ok(Got::String { head, cut })
    }

    fn visit_unit<E: de::Error>(self) -> Result<Got, E> {
        Ok(Got::Null)
    }

    fn visit_none<E: de::Error>(self) -> Result<Got, E> {
        Ok(Got::Null)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Got, A::Error> {
        match self.into {
            // An array where an object is expected: skipped, the caller reports the type.
            Target::Message { .. } | Target::Pose(_) => {
                while seq.next_element::<IgnoredAny>()?.is_some() {}
            }
            Target::Angles {
                angles,
                joint_count,
            } => {
                *angles = AngleArray::default();
                angles.values.reserve_exact(joint_count);
                loop {
                    let path = Path {
                        parent: self.path,
                        segment: Segment::Index(angles.count),
                    };
                    let item = seq.next_element_seed(Probe {
                        into: Target::Value,
                        path: Some(&path),
                        trace: &mut *self.trace,
                    });
                    match self.trace.located(item, &path)? {
                        None => break,
                        Some(Got::Number(number)) if angles.count < joint_count => {
                            angles.values.push(number.to_f64());
                        }
                        Some(Got::Number(_)) => {}
                        Some(other) => {
                            if angles.first_non_number.is_none() {
                                angles.first_non_number = Some((angles.count, other));
                            }
                        }
                    }
                    angles.count += 1;
                }
            }
            Target::Value | Target::WholeString => {
                for index in 0.. {
                    let path = Path {
                        parent: self.path,
                        segment: Segment::Index(index),
                    };
                    let item = seq.next_element_seed(Probe {
                        into: Target::Value,
                        path: Some(&path),
                        trace: &mut *self.trace,
                    });
                    if self.trace.located(item, &path)?.is_none() {
                        break;
                    }
                }
            }
        }
        Ok(Got::Array)
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Got, A::Error> {
        match self.into {
            Target::Message { schema, slots } => read_members(&mut map, schema, slots, self.trace)?,
            Target::Pose(pose) => {
                *pose = PoseSlots::default();
                while let Some(key) = map.next_key_seed(KeySeed(pose_key))? {
                    let Some(index) = key else {
                        map.next_value::<IgnoredAny>()?;
                        continue;
                    };
                    let path = Path {
                        parent: self.path,
                        segment: Segment::Key(POSE_KEYS[index]),
                    };
                    let slot = &mut pose[index];
                    let repeated = slot.is_some();
                    keep(
                        &mut map,
                        slot,
                        repeated,
                        Target::Value,
                        &path,
                        &mut *self.trace,
                    )?;
                }
            }
            Target::Value | Target::WholeString | Target::Angles { .. } => {
                // Kept only to notice a repeated key; empty (unallocated) for most values.
                let mut keys = BTreeSet::new();
                while let Some(key) = map.next_key::<String>()? {
                    let path = Path {
                        parent: self.path,
                        segment: Segment::Key(&key),
                    };
                    if keys.contains(&key) {
                        self.trace.note_repeated(&path);
                    }
                    let value = map.next_value_seed(Probe {
                        into: Target::Value,
                        path: Some(&path),
                        trace: &mut *self.trace,
                    });
                    self.trace.located(value, &path)?;
                    keys.insert(key);
                }
            }
        }
        Ok(Got::Object)
    }
}

/// The members of a message's top-level object.
fn read_members<'de, A: MapAccess<'de>>(
    map: &mut A,
    schema: Schema,
    slots: &mut MessageSlots,
    trace: &mut Trace,
) -> Result<(), A::Error> {
    let joint_count = match schema {
        Schema::Joints { joint_count } => joint_count,
        Schema::Measured | Schema::Stamp => 0,
    };
    while let Some(key) = map.next_key_seed(KeySeed(|key: &str| MessageKey::of(schema, key)))? {
        let (slot, into, segment) = match key {
            MessageKey::T => (&mut slots.t, Target::Value, Segment::Key("t")),
            MessageKey::Time => (&mut slots.time, Target::Value, Segment::Key("time")),
            MessageKey::Seq => (&mut slots.seq, Target::Value, Segment::Key("seq")),
            MessageKey::Unit => (&mut slots.unit, Target::WholeString, Segment::Key("unit")),
            MessageKey::Q => (
                &mut slots.q,
                Target::Angles {
                    angles: &mut slots.angles,
                    joint_count,
                },
                Segment::Key("q"),
            ),
            MessageKey::Measured => (
                &mut slots.measured,
                Target::Pose(&mut slots.measured_pose),
                Segment::Key("measured"),
            ),
            MessageKey::Pose(index) => (
                &mut slots.pose[index],
                Target::Value,
                Segment::Key(POSE_KEYS[index]),
            ),
            MessageKey::Joint(n) => {
                let (slot, repeated) = slots.flat.slot(n, joint_count);
                let path = Path {
                    parent: None,
                    segment: Segment::Joint(n),
                };
                keep(map, slot, repeated, Target::Value, &path, trace)?;
                continue;
            }
            MessageKey::State => {
                if slots.state.is_some() {
                    trace.note_repeated(&Path {
                        parent: None,
                        segment: Segment::Key("state"),
                    });
                }
                slots.state = Some(map.next_value::<Value>()?);
                continue;
            }
            MessageKey::Other => {
                map.next_value::<IgnoredAny>()?;
                continue;
            }
        };
        let path = Path {
            parent: None,
            segment,
        };
        let repeated = slot.is_some();
        keep(map, slot, repeated, into, &path, trace)?;
    }
    Ok(())
}

/// Reads the value of a kept field into `slot` (a repeated field's last value wins, and the
/// repetition is noted).
fn keep<'de, A: MapAccess<'de>>(
    map: &mut A,
    slot: &mut Option<Got>,
    repeated: bool,
    into: Target<'_>,
    path: &Path<'_>,
    trace: &mut Trace,
) -> Result<(), A::Error> {
    if repeated {
        trace.note_repeated(path);
    }
    let got = map.next_value_seed(Probe {
        into,
        path: Some(path),
        trace: &mut *trace,
    });
    *slot = Some(trace.located(got, path)?);
    Ok(())
}

/// Reads an object key as what `classify` makes of it, without copying it.
struct KeySeed<F>(F);

impl<'de, K, F: FnOnce(&str) -> K> DeserializeSeed<'de> for KeySeed<F> {
    type Value = K;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<K, D::Error> {
        deserializer.deserialize_str(self)
    }
}

impl<K, F: FnOnce(&str) -> K> Visitor<'_> for KeySeed<F> {
    type Value = K;

    fn expecting(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        formatter.write_str("an object key")
    }

    fn visit_str<E: de::Error>(self, key: &str) -> Result<K, E> {
        Ok((self.0)(key))
    }
}
