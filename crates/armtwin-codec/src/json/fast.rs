//! The fast path: well-formed messages in their usual shapes, read by a small scanner straight
//! into fixed slots, without building a `Value` tree and without `serde`.
//!
//! It never reports an error: anything unusual (a `null`, a repeated field, a wrong type, an
//! escape in a key or a string it must read, a non-finite number, a failed check) makes it give
//! up, and the general decoder reads the message again and names the problem exactly. So both
//! paths agree by construction on every message the fast one accepts (tested in the crate's
//! `json_paths` tests).
//!
//! Numbers are checked against JSON's grammar, then converted by the standard library's
//! correctly rounded `f64` parser: the same value `serde_json` (with `float_roundtrip`) gives.
//! Fields it does not know are skipped after checking that they are well-formed JSON, as the
//! general decoder skips them.

use super::MAX_PAYLOAD_BYTES;
use super::joints::DecodedJoints;
use super::pose::{OrientationForm, pose_of};
use super::slots::joint_index;
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::sample::{JointAngles, JointSample, MeasuredSample};

/// Nesting the skipper follows inside an unknown field before it gives up.
const MAX_SKIP_DEPTH: usize = 32;

/// A position in the payload (valid UTF-8, checked once).
struct Scanner<'a> {
    text: &'a str,
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Scanner<'a> {
    fn new(text: &'a str) -> Self {
        Self {
            text,
            bytes: text.as_bytes(),
            at: 0,
        }
    }

    /// The next byte after whitespace, not consumed.
    fn peek(&mut self) -> Option<u8> {
        while let Some(&byte) = self.bytes.get(self.at) {
            if !matches!(byte, b' ' | b'\t' | b'\n' | b'\r') {
                return Some(byte);
            }
            self.at += 1;
        }
        None
    }

    /// Consumes `byte` (after whitespace), or gives up.
    fn expect(&mut self, byte: u8) -> Option<()> {
        (self.peek()? == byte).then(|| self.at += 1)
    }

    /// Only whitespace is left.
    fn at_end(&mut self) -> bool {
        self.peek().is_none()
    }

    /// A string's contents without its quotes, when it has no escape.
    fn plain_string(&mut self) -> Option<&'a [u8]> {
        self.expect(b'"')?;
        let start = self.at;
        loop {
            match *self.bytes.get(self.at)? {
                b'"' => break,
                b'\\' | 0..0x20 => return None,
                _ => self.at += 1,
            }
        }
        let text = &self.bytes[start..self.at];
        self.at += 1;
        Some(text)
    }

    /// The text of a number, checked against JSON's grammar:
    /// `-?(0|[1-9][0-9]*)(\.[0-9]+)?([eE][+-]?[0-9]+)?`.
    fn number_text(&mut self) -> Option<&'a str> {
        self.peek()?;
        let start = self.at;
        self.skip_if(b'-');
        match self.bytes.get(self.at)? {
            b'0' => self.at += 1,
            b'1'..=b'9' => self.digits(),
            _ => return None,
        }
        if self.skip_if(b'.') {
            self.required_digits()?;
        }
        if self.skip_if(b'e') || self.skip_if(b'E') {
            if !self.skip_if(b'+') {
                self.skip_if(b'-');
            }
            self.required_digits()?;
        }
        self.text.get(start..self.at)
    }

    /// A finite number.
    fn number(&mut self) -> Option<f64> {
        let value: f64 = self.number_text()?.parse().ok()?;
        value.is_finite().then_some(value)
    }

    /// A non-negative integer that fits a `u64`.
    fn unsigned(&mut self) -> Option<u64> {
        let text = self.number_text()?;
        if !text.bytes().all(|byte| byte.is_ascii_digit()) {
            return None;
        }
        text.parse().ok()
    }

    fn skip_if(&mut self, byte: u8) -> bool {
        let found = self.bytes.get(self.at) == Some(&byte);
        if found {
            self.at += 1;
        }
        found
    }

    fn digits(&mut self) {
        while self.bytes.get(self.at).is_some_and(u8::is_ascii_digit) {
            self.at += 1;
        }
    }

    fn required_digits(&mut self) -> Option<()> {
        let start = self.at;
        self.digits();
        (self.at > start).then_some(())
    }

    /// Skips one well-formed value of any type.
    fn skip_value(&mut self, depth: usize) -> Option<()> {
        if depth > MAX_SKIP_DEPTH {
            return None;
        }
        match self.peek()? {
            b'"' => self.plain_string().map(drop),
            b'{' => {
                self.at += 1;
                if self.peek()? == b'}' {
                    self.at += 1;
                    return Some(());
                }
                loop {
                    self.plain_string()?;
                    self.expect(b':')?;
                    self.skip_value(depth + 1)?;
                    if !self.comma_or_end(b'}')? {
                        return Some(());
                    }
                }
            }
            b'[' => {
                self.at += 1;
                if self.peek()? == b']' {
                    self.at += 1;
                    return Some(());
                }
                loop {
                    self.skip_value(depth + 1)?;
                    if !self.comma_or_end(b']')? {
                        return Some(());
                    }
                }
            }
            b't' => self.literal(b"true"),
            b'f' => self.literal(b"false"),
            b'n' => self.literal(b"null"),
            _ => self.number_text().map(drop),
        }
    }

    fn literal(&mut self, word: &[u8]) -> Option<()> {
        let end = self.at + word.len();
        (self.bytes.get(self.at..end)? == word).then(|| self.at = end)
    }

    /// After a member: `true` after a comma (another member follows), `false` after `close`.
    fn comma_or_end(&mut self, close: u8) -> Option<bool> {
        let byte = self.peek()?;
        self.at += 1;
        match byte {
            b',' => Some(true),
            _ if byte == close => Some(false),
            _ => None,
        }
    }

    /// Reads an object's members, handing each key to `member`, which must consume the value.
    fn object(&mut self, mut member: impl FnMut(&mut Self, &'a [u8]) -> Option<()>) -> Option<()> {
        self.expect(b'{')?;
        if self.peek()? == b'}' {
            self.at += 1;
            return Some(());
        }
        loop {
            let key = self.plain_string()?;
            self.expect(b':')?;
            member(self, key)?;
            if !self.comma_or_end(b'}')? {
                return Some(());
            }
        }
    }
}

/// Sets a slot once; a repeated field gives up.
fn once<T>(slot: &mut Option<T>, value: T) -> Option<()> {
    slot.replace(value).is_none().then_some(())
}

/// The fields of a measured pose object.
#[derive(Default)]
struct PoseSlots {
    stamp_s: Option<f64>,
    time_s: Option<f64>,
    position_m: [Option<f64>; 3],
    /// `qx, qy, qz, qw`, `roll, pitch, yaw` and `rx, ry, rz`, in [`OrientationForm::ALL`] order.
    forms: [[Option<f64>; 4]; 3],
}

impl PoseSlots {
    /// Reads a measured pose object; `with_stamp` reads its `t`/`time` (a joint message's
    /// embedded pose skips them, as the general decoder does).
    fn read(scanner: &mut Scanner<'_>, with_stamp: bool) -> Option<Self> {
        let mut slots = Self::default();
        scanner.object(|scanner, key| {
            let slot = match key {
                b"t" if with_stamp => Some(&mut slots.stamp_s),
                b"time" if with_stamp => Some(&mut slots.time_s),
                other => slots.slot(other),
            };
            match slot {
                Some(slot) => once(slot, scanner.number()?),
                None => scanner.skip_value(0),
            }
        })?;
        Some(slots)
    }

    /// The slot of a pose field, if `key` is one.
    fn slot(&mut self, key: &[u8]) -> Option<&mut Option<f64>> {
        let [quaternion, rpy, rotation_vector] = &mut self.forms;
        Some(match key {
            b"x" => &mut self.position_m[0],
            b"y" => &mut self.position_m[1],
            b"z" => &mut self.position_m[2],
            b"qx" => &mut quaternion[0],
            b"qy" => &mut quaternion[1],
            b"qz" => &mut quaternion[2],
            b"qw" => &mut quaternion[3],
            b"roll" => &mut rpy[0],
            b"pitch" => &mut rpy[1],
            b"yaw" => &mut rpy[2],
            b"rx" => &mut rotation_vector[0],
            b"ry" => &mut rotation_vector[1],
            b"rz" => &mut rotation_vector[2],
            _ => return None,
        })
    }

    /// The pose, if every position field and exactly one complete orientation form is present
    /// and it passes the general decoder's checks.
    fn pose(&self, prefix: &str) -> Option<PoseReadout> {
        let [Some(x), Some(y), Some(z)] = self.position_m else {
            return None;
        };
        let mut present = OrientationForm::ALL
            .into_iter()
            .zip(&self.forms)
            .filter(|(_, values)| values.iter().any(Option::is_some));
        let (form, values) = present.next()?;
        if present.next().is_some() {
            return None;
        }
        let mut numbers = [0.0; 4];
        for (index, number) in numbers.iter_mut().enumerate().take(form.keys().len()) {
            *number = values[index]?;
        }
        pose_of(prefix, [x, y, z], form, numbers).ok()
    }
}

/// A message gave both `t` and `time` (the general decoder names the problem).
struct BothStamps;

/// The message's stamp from `t` and `time`, if any.
fn stamp_of(stamp_s: Option<f64>, time_s: Option<f64>) -> Result<Option<f64>, BothStamps> {
    match (stamp_s, time_s) {
        (Some(_), Some(_)) => Err(BothStamps),
        (stamp_s, time_s) => Ok(stamp_s.or(time_s)),
    }
}

/// Exactly `joint_count` finite numbers in an array.
fn angles(scanner: &mut Scanner<'_>, joint_count: usize) -> Option<JointAngles> {
    scanner.expect(b'[')?;
    let mut angles = JointAngles::with_capacity(joint_count);
    if scanner.peek()? == b']' {
        scanner.at += 1;
    } else {
        loop {
            if angles.len() == joint_count {
                return None;
            }
            angles.push(scanner.number()?);
            if !scanner.comma_or_end(b']')? {
                break;
            }
        }
    }
    (angles.len() == joint_count).then_some(angles)
}

/// Parses the whole payload with `read`, requiring nothing but whitespace after it.
fn whole<'a, T>(payload: &'a [u8], read: impl FnOnce(&mut Scanner<'a>) -> Option<T>) -> Option<T> {
    if payload.len() > MAX_PAYLOAD_BYTES {
        return None;
    }
    let mut scanner = Scanner::new(std::str::from_utf8(payload).ok()?);
    let value = read(&mut scanner)?;
    scanner.at_end().then_some(value)
}

/// A joint message in its usual shape, or `None` for the general decoder.
#[must_use]
pub fn joints(payload: &[u8], joint_count: usize) -> Option<DecodedJoints> {
    let mut stamp_s = None;
    let mut time_s = None;
    let mut seq = None;
    let mut degrees = None;
    let mut q_rad = None;
    let mut measured = None;
    whole(payload, |scanner| {
        scanner.object(|scanner, key| match key {
            b"t" => once(&mut stamp_s, scanner.number()?),
            b"time" => once(&mut time_s, scanner.number()?),
            b"seq" => once(&mut seq, scanner.unsigned()?),
            b"unit" => {
                let unit = match scanner.plain_string()? {
                    b"rad" => false,
                    b"deg" => true,
                    _ => return None,
                };
                once(&mut degrees, unit)
            }
            b"q" => once(&mut q_rad, angles(scanner, joint_count)?),
            b"measured" => once(&mut measured, PoseSlots::read(scanner, false)?),
            // The flat `q1..qn` form: the general decoder.
            other
                if std::str::from_utf8(other)
                    .ok()
                    .and_then(joint_index)
                    .is_some() =>
            {
                None
            }
            // The joint state is the general decoder's: it names every field it refuses.
            b"state" => None,
            _ => scanner.skip_value(0),
        })
    })?;
    let mut q_rad = q_rad?;
    if degrees == Some(true) {
        for angle in &mut q_rad {
            *angle = angle.to_radians();
        }
    }
    let measured = match &measured {
        Some(pose) => Some(pose.pose("measured.")?),
        None => None,
    };
    Some(DecodedJoints {
        sample: JointSample {
            stamp_s: stamp_of(stamp_s, time_s).ok()?,
            seq,
            q_rad,
            measured,
            state: None,
        },
        measured_error: None,
        state_error: None,
    })
}

/// A measured pose in its usual shape, or `None` for the general decoder.
#[must_use]
pub fn measured(payload: &[u8]) -> Option<MeasuredSample> {
    let slots = whole(payload, |scanner| PoseSlots::read(scanner, true))?;
    Some(MeasuredSample {
        stamp_s: stamp_of(slots.stamp_s, slots.time_s).ok()?,
        pose: slots.pose("")?,
    })
}
