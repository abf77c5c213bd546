//! Recordings of joint angles (and the controller's measured pose) as people have them, read into
//! rows that become the service's joint messages.
//!
//! Recognised from the header:
//! - the UR10e FMU report's form (`fmpy_inputs.csv`, its `FMPy` input): `time, q1..q6` and
//!   optionally `x, y, z` with `qx, qy, qz, qw` (preferred) or `roll, pitch, yaw`;
//! - ROS 2 exports (`ur10e_lasttest.csv`): `header.stamp.sec` (and `.nanosec`), the six
//!   `<joint>.position` columns, `tcp_pose.position.*`, `tcp_pose.orientation.*`;
//! - Universal Robots RTDE recordings: `timestamp`, `actual_q_0..5`, `actual_TCP_pose_0..5`
//!   (position and rotation vector), comma- or space-separated, other columns ignored.
//!
//! Each row turns into exactly the JSON message a gateway would publish
//! ([`RecordingRow::to_message`]), so replaying a recording into the service and running it
//! through the decoder offline are one path. Cells that are not numbers stay text and are refused
//! by the decoder like any bad message; rows that cannot be split into the header's columns are
//! kept as [`Malformed`]. Lines are read with the `csv` crate (see `RecordLines` for the
//! separators and why quotes are not special).

use serde_json::{Map, Value, json};
use thiserror::Error;

/// The recording layouts armtwin recognises.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// `time, q1..q6[, x, y, z, qx, qy, qz, qw | roll, pitch, yaw]` (the UR10e FMU report's `FMPy` input).
    FmpyInputs,
    /// A ROS 2 export of `/joint_states` and the TCP pose.
    Ros2,
    /// A UR RTDE recording (`record.py`, `ur_rtde`).
    Rtde,
    /// Columns named on the command line ([`ColumnMap`]).
    Mapped,
    /// A rosbag2 recording of `JointState` and `PoseStamped` topics (read by `armtwin_offline::rosbag`).
    Rosbag2,
}

impl Format {
    /// A name for messages.
    #[must_use]
    pub fn describe(self) -> &'static str {
        match self {
            Self::FmpyInputs => "FMPy input form (time, q1..q6, x..qw)",
            Self::Ros2 => "ROS 2 export (header.stamp, <joint>.position, tcp_pose.*)",
            Self::Rtde => "UR RTDE recording (timestamp, actual_q_*, actual_TCP_pose_*)",
            Self::Mapped => "columns mapped on the command line",
            Self::Rosbag2 => "rosbag2 recording (JointState and PoseStamped topics)",
        }
    }
}

/// One cell: a number, or the text that did not parse as one.
#[derive(Debug, Clone, PartialEq)]
pub enum Cell {
    /// A number.
    Number(f64),
    /// Anything else, kept for the decoder to refuse by name.
    Text(String),
}

impl Cell {
    /// A finite number, or the text as written (`nan` and `inf` stay text: JSON has no such
    /// numbers, and the decoder's message then quotes what the file holds).
    fn parse(text: &str) -> Self {
        let text = text.trim();
        match text.parse::<f64>() {
            Ok(number) if number.is_finite() => Self::Number(number),
            _ => Self::Text(text.to_owned()),
        }
    }

    fn to_json(&self) -> Value {
        match self {
            Self::Number(n) => json!(n),
            Self::Text(t) => json!(t),
        }
    }

    /// The number, if it is one.
    #[must_use]
    pub fn number(&self) -> Option<f64> {
        match self {
            Self::Number(n) => Some(*n),
            Self::Text(_) => None,
        }
    }
}

/// The measured-pose cells of a row, in their recorded orientation form.
#[derive(Debug, Clone, PartialEq)]
pub enum PoseCells {
    /// `x, y, z, qx, qy, qz, qw`.
    Quaternion([Cell; 7]),
    /// `x, y, z, roll, pitch, yaw`.
    Rpy([Cell; 6]),
    /// `x, y, z, rx, ry, rz` (UR rotation vector).
    RotationVector([Cell; 6]),
}

/// One recorded row.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordingRow {
    /// 1-based line in the file.
    pub line: u64,
    /// The recorded time (s), if the row has a usable one.
    pub stamp_s: Option<f64>,
    /// Joint angles (rad), one cell each.
    pub q: Vec<Cell>,
    /// The measured pose, if the recording has one.
    pub pose: Option<PoseCells>,
}

/// A line that does not split into the header's columns.
#[derive(Debug, Clone, PartialEq)]
pub struct Malformed {
    /// 1-based line in the file.
    pub line: u64,
    /// The line.
    pub text: String,
    /// What is wrong.
    pub problem: String,
}

/// A whole recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The layout recognised.
    pub format: Format,
    /// Whether rows carry a measured pose.
    pub has_pose: bool,
    /// Rows and malformed lines, in file order.
    pub entries: Vec<Result<RecordingRow, Malformed>>,
}

/// Why a recording cannot be used at all.
#[derive(Debug, Error)]
pub enum RecordingError {
    /// The file is empty.
    #[error("the recording is empty")]
    Empty,
    /// A column named in a [`ColumnMap`] is not in the header.
    #[error("column '{column}' is not in the header; the header has: {header}")]
    MissingColumn {
        /// The column asked for.
        column: String,
        /// The header's column names.
        header: String,
    },
    /// A [`ColumnMap`] names the wrong number of pose columns for its form.
    #[error("a {form:?} pose has {expected} columns, {got} were named")]
    PoseColumnCount {
        /// The form.
        form: PoseForm,
        /// Columns the form has.
        expected: usize,
        /// Columns named.
        got: usize,
    },
    /// The header matches no known layout.
    #[error(
        "header not recognised: expected the FMPy input form 'time,q1..q6[,x,y,z,qx,qy,qz,qw]', a ROS 2 export ('header.stamp.sec', '<joint>.position', 'tcp_pose.*') or an RTDE recording ('timestamp', 'actual_q_0..5', 'actual_TCP_pose_0..5'); found: {header}"
    )]
    UnknownHeader {
        /// The header line.
        header: String,
    },
}

const ROS_JOINTS: [&str; 6] = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
];

/// Column indices of one layout.
struct Layout {
    format: Format,
    stamp: Vec<usize>,
    /// Seconds per unit of each stamp column (`header.stamp.nanosec` is 1e-9).
    stamp_scale: Vec<f64>,
    q: Vec<usize>,
    pose: Option<(PoseForm, Vec<usize>)>,
}

/// The orientation form of a recording's measured pose columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseForm {
    /// `x, y, z, qx, qy, qz, qw`.
    Quaternion,
    /// `x, y, z, roll, pitch, yaw` (rad).
    Rpy,
    /// `x, y, z, rx, ry, rz` (UR rotation vector, rad).
    RotationVector,
}

impl PoseForm {
    /// How many columns the form has.
    #[must_use]
    pub fn column_count(self) -> usize {
        match self {
            Self::Quaternion => 7,
            Self::Rpy | Self::RotationVector => 6,
        }
    }
}

/// Columns named explicitly, for a recording whose header armtwin does not recognise (or to
/// override what it recognises).
#[derive(Debug, Clone, PartialEq)]
pub struct ColumnMap {
    /// The time column, if any.
    pub time: Option<String>,
    /// Seconds per unit of the time column (1e-3 for milliseconds).
    pub time_scale_s: f64,
    /// The joint angle columns, in joint order.
    pub joints: Vec<String>,
    /// The measured pose columns and their form, if any.
    pub pose: Option<(PoseForm, Vec<String>)>,
}

fn find_all(names: &[&str], wanted: &[String]) -> Option<Vec<usize>> {
    wanted
        .iter()
        .map(|w| names.iter().position(|n| n.eq_ignore_ascii_case(w)))
        .collect()
}

fn layout(names: &[&str]) -> Option<Layout> {
    let strings = |items: &[&str]| items.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>();
    let q_columns = (1..=6).map(|j| format!("q{j}")).collect::<Vec<_>>();
    if let Some(q) = find_all(names, &q_columns) {
        let stamp = find_all(names, &strings(&["time"])).unwrap_or_default();
        let pose = find_all(names, &strings(&["x", "y", "z", "qx", "qy", "qz", "qw"]))
            .map(|c| (PoseForm::Quaternion, c))
            .or_else(|| {
                find_all(names, &strings(&["x", "y", "z", "roll", "pitch", "yaw"]))
                    .map(|c| (PoseForm::Rpy, c))
            });
        return Some(Layout {
            format: Format::FmpyInputs,
            stamp_scale: vec![1.0; stamp.len()],
            stamp,
            q,
            pose,
        });
    }
    let q_ros = ROS_JOINTS
        .iter()
        .map(|j| format!("{j}.position"))
        .collect::<Vec<_>>();
    if let Some(q) = find_all(names, &q_ros) {
        let (stamp, stamp_scale) = match find_all(
            names,
            &strings(&["header.stamp.sec", "header.stamp.nanosec"]),
        ) {
            Some(both) => (both, vec![1.0, 1e-9]),
            None => (
                find_all(names, &strings(&["header.stamp.sec"])).unwrap_or_default(),
                vec![1.0],
            ),
        };
        let pose_columns = [
            "tcp_pose.position.x",
            "tcp_pose.position.y",
            "tcp_pose.position.z",
            "tcp_pose.orientation.x",
            "tcp_pose.orientation.y",
            "tcp_pose.orientation.z",
            "tcp_pose.orientation.w",
        ];
        return Some(Layout {
            format: Format::Ros2,
            stamp_scale,
            stamp,
            q,
            pose: find_all(names, &strings(&pose_columns)).map(|c| (PoseForm::Quaternion, c)),
        });
    }
    let q_rtde = (0..6).map(|j| format!("actual_q_{j}")).collect::<Vec<_>>();
    if let Some(q) = find_all(names, &q_rtde) {
        let stamp = find_all(names, &strings(&["timestamp"])).unwrap_or_default();
        let pose_columns = (0..6)
            .map(|j| format!("actual_TCP_pose_{j}"))
            .collect::<Vec<_>>();
        return Some(Layout {
            format: Format::Rtde,
            stamp_scale: vec![1.0; stamp.len()],
            stamp,
            q,
            pose: find_all(names, &pose_columns).map(|c| (PoseForm::RotationVector, c)),
        });
    }
    None
}

/// The lines of a recording that hold something, read with the `csv` crate: each with its 1-based
/// line number, its text as in the file, and its cells.
///
/// The separator is the header's: a comma when the header line has one, else white space (UR's
/// RTDE `record.py` writes single spaces; runs of spaces and tabs, as in aligned columns, are
/// accepted too: the reader splits on spaces and each piece is split again on any white space,
/// which drops the empty pieces a run of spaces leaves). Quotes are not special, and one line is
/// one record: the ROS 2 sample export has whole lines quoted around numbers written with
/// thousands separators (`"…,""8.506,978,778,163,627e-7"",0.011"`); read as CSV quoting they
/// would become rows of other cells, and an unbalanced quote in a truncated line would swallow the
/// lines after it. Such a line does not split into the header's columns and is reported malformed,
/// which is what it is.
///
/// Line numbers and text come from each record's byte offset, not from `csv::Position::line`,
/// which names the wrong line for the record after an empty line (rust-csv issue 208).
struct RecordLines<'t> {
    text: &'t str,
    reader: csv::Reader<&'t [u8]>,
    comma: bool,
    /// The last record read, as the reader split it.
    record: csv::StringRecord,
    /// Its cells: `record` itself, or its white-space-separated pieces.
    pieces: csv::StringRecord,
    /// Bytes of `text` whose line feeds are counted in `line`.
    counted: usize,
    /// 1-based line of byte `counted`.
    line: u64,
}

/// Where a line of a recording that is not blank is.
struct RecordLine<'t> {
    /// 1-based line in the file.
    line: u64,
    /// The line as written (without its line ending).
    text: &'t str,
}

impl<'t> RecordLines<'t> {
    fn new(text: &'t str) -> Self {
        let comma = text
            .lines()
            .find(|line| !line.trim().is_empty())
            .is_some_and(|header| header.contains(','));
        let reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .quoting(false)
            .trim(csv::Trim::All)
            .delimiter(if comma { b',' } else { b' ' })
            // Lines end at a line feed, as `str::lines` has them; a carriage return before it is
            // trimmed with the last cell.
            .terminator(csv::Terminator::Any(b'\n'))
            .from_reader(text.as_bytes());
        Self {
            text,
            reader,
            comma,
            record: csv::StringRecord::new(),
            pieces: csv::StringRecord::new(),
            counted: 0,
            line: 1,
        }
    }

    /// Reads the next line that is not blank; its cells are then [`Self::cells`].
    fn advance(&mut self) -> Option<RecordLine<'t>> {
        loop {
            // The input is a `str` and quoting is off: a record is one line of valid UTF-8,
            // and reading from memory cannot fail; an error ends the recording where it occurs.
            if !self.reader.read_record(&mut self.record).ok()? {
                return None;
            }
            let offset = self
                .record
                .position()
                .and_then(|position| usize::try_from(position.byte()).ok())
                .unwrap_or(self.counted);
            let rest = self.text.get(offset..)?;
            // The record's offset is where the previous one ended: skip the empty lines the
            // reader passed over.
            let start = offset + (rest.len() - rest.trim_start_matches('\n').len());
            let before = self.text.get(self.counted..start)?;
            self.line += before.bytes().filter(|&b| b == b'\n').count() as u64;
            self.counted = start;
            let text = self.text.get(start..)?;
            let text = text.split('\n').next().unwrap_or_default();
            let text = text.strip_suffix('\r').unwrap_or(text);
            if text.trim().is_empty() {
                continue;
            }
            if !self.comma {
                self.pieces.clear();
                for piece in self.record.iter().flat_map(str::split_whitespace) {
                    self.pieces.push_field(piece);
                }
            }
            return Some(RecordLine {
                line: self.line,
                text,
            });
        }
    }

    /// The cells of the line [`Self::advance`] returned last.
    fn cells(&self) -> &csv::StringRecord {
        if self.comma {
            &self.record
        } else {
            &self.pieces
        }
    }
}

/// The layout a [`ColumnMap`] names.
fn mapped_layout(names: &[&str], map: &ColumnMap) -> Result<Layout, RecordingError> {
    let index_of = |column: &String| {
        names
            .iter()
            .position(|n| n.eq_ignore_ascii_case(column))
            .ok_or_else(|| RecordingError::MissingColumn {
                column: column.clone(),
                header: names.join(", ").chars().take(400).collect(),
            })
    };
    let stamp = map
        .time
        .iter()
        .map(index_of)
        .collect::<Result<Vec<_>, _>>()?;
    let q = map
        .joints
        .iter()
        .map(index_of)
        .collect::<Result<Vec<_>, _>>()?;
    let pose = match &map.pose {
        None => None,
        Some((form, columns)) => {
            if columns.len() != form.column_count() {
                return Err(RecordingError::PoseColumnCount {
                    form: *form,
                    expected: form.column_count(),
                    got: columns.len(),
                });
            }
            Some((
                *form,
                columns.iter().map(index_of).collect::<Result<_, _>>()?,
            ))
        }
    };
    Ok(Layout {
        format: Format::Mapped,
        stamp_scale: vec![map.time_scale_s; stamp.len()],
        stamp,
        q,
        pose,
    })
}

/// Named numeric columns of a recording's data lines (`armtwin validate --dynamics` reads a UR
/// RTDE recording's currents, targets and payload this way, beside its joint rows).
#[derive(Debug, Clone, PartialEq)]
pub struct ColumnTable {
    /// Per name asked for, whether the header has it (compared case-insensitively).
    pub found: Vec<bool>,
    /// Per data line: its 1-based line number and, per name, the cell's number if it has one.
    /// A line that does not split into the header's columns has no numbers.
    pub rows: Vec<(u64, Vec<Option<f64>>)>,
}

/// Reads the columns `names` of every data line of `text`, with the separators and line numbers
/// of [`read`].
pub fn read_columns(text: &str, names: &[&str]) -> Result<ColumnTable, RecordingError> {
    let mut lines = RecordLines::new(text);
    lines.advance().ok_or(RecordingError::Empty)?;
    let header: Vec<String> = lines.cells().iter().map(str::to_owned).collect();
    let indices: Vec<Option<usize>> = names
        .iter()
        .map(|name| header.iter().position(|h| h.eq_ignore_ascii_case(name)))
        .collect();
    let mut rows = Vec::new();
    while let Some(line) = lines.advance() {
        let cells = lines.cells();
        let whole = cells.len() == header.len();
        let values = indices
            .iter()
            .map(|index| {
                index
                    .filter(|_| whole)
                    .and_then(|i| cells.get(i))
                    .and_then(|cell| cell.parse::<f64>().ok())
            })
            .collect();
        rows.push((line.line, values));
    }
    Ok(ColumnTable {
        found: indices.iter().map(Option::is_some).collect(),
        rows,
    })
}

/// Reads a recording whose layout is recognised from its header.
pub fn read(text: &str) -> Result<Recording, RecordingError> {
    read_with(text, None)
}

/// Reads a recording, with the columns named by `map` when given (else recognised from the
/// header).
pub fn read_with(text: &str, map: Option<&ColumnMap>) -> Result<Recording, RecordingError> {
    let mut lines = RecordLines::new(text);
    let header = lines.advance().ok_or(RecordingError::Empty)?;
    let names: Vec<String> = lines.cells().iter().map(str::to_owned).collect();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let layout = match map {
        Some(map) => mapped_layout(&names, map)?,
        None => layout(&names).ok_or_else(|| RecordingError::UnknownHeader {
            header: header.text.chars().take(200).collect(),
        })?,
    };
    let mut entries = Vec::new();
    while let Some(RecordLine { line, text }) = lines.advance() {
        let cells = lines.cells();
        if cells.len() != names.len() {
            entries.push(Err(Malformed {
                line,
                text: text.to_owned(),
                problem: format!("{} columns, the header has {}", cells.len(), names.len()),
            }));
            continue;
        }
        let stamp_s = layout
            .stamp
            .iter()
            .zip(&layout.stamp_scale)
            .map(|(&c, scale)| Cell::parse(&cells[c]).number().map(|v| v * scale))
            .sum::<Option<f64>>()
            .filter(|_| !layout.stamp.is_empty())
            .filter(|t| t.is_finite());
        let q = layout.q.iter().map(|&c| Cell::parse(&cells[c])).collect();
        let pose = layout.pose.as_ref().map(|(form, columns)| {
            let cell = |i: usize| Cell::parse(&cells[columns[i]]);
            match form {
                PoseForm::Quaternion => PoseCells::Quaternion(std::array::from_fn(cell)),
                PoseForm::Rpy => PoseCells::Rpy(std::array::from_fn(cell)),
                PoseForm::RotationVector => PoseCells::RotationVector(std::array::from_fn(cell)),
            }
        });
        entries.push(Ok(RecordingRow {
            line,
            stamp_s,
            q,
            pose,
        }));
    }
    Ok(Recording {
        format: layout.format,
        has_pose: layout.pose.is_some(),
        entries,
    })
}

impl RecordingRow {
    /// The joint message a gateway would publish for this row at source time `t_s`.
    #[must_use]
    pub fn to_message(&self, t_s: f64) -> Value {
        let mut message = Map::new();
        message.insert("t".to_owned(), json!(t_s));
        message.insert(
            "q".to_owned(),
            Value::Array(self.q.iter().map(Cell::to_json).collect()),
        );
        if let Some(pose) = &self.pose {
            let (names, cells): (&[&str], &[Cell]) = match pose {
                PoseCells::Quaternion(c) => (&["x", "y", "z", "qx", "qy", "qz", "qw"], c),
                PoseCells::Rpy(c) => (&["x", "y", "z", "roll", "pitch", "yaw"], c),
                PoseCells::RotationVector(c) => (&["x", "y", "z", "rx", "ry", "rz"], c),
            };
            let measured = names
                .iter()
                .zip(cells)
                .map(|(name, cell)| ((*name).to_owned(), cell.to_json()))
                .collect();
            message.insert("measured".to_owned(), Value::Object(measured));
        }
        Value::Object(message)
    }
}

/// The bytes a gateway publishes for one entry at source time `t_s`: a row's joint message, or a
/// malformed line's raw text (which the service rejects and counts, as it would from a gateway).
/// `armtwin replay` publishes exactly these bytes and `armtwin validate` decodes exactly these.
#[must_use]
pub fn payload(entry: &Result<RecordingRow, Malformed>, t_s: f64) -> Vec<u8> {
    match entry {
        Ok(row) => row.to_message(t_s).to_string().into_bytes(),
        Err(malformed) => malformed.text.clone().into_bytes(),
    }
}

/// Source times for every entry, strictly increasing where the recording allows.
///
/// With `period_s`, entry k is at `k · period_s`. Otherwise the recorded stamps are used; where a
/// run of rows shares one stamp (a time column coarser than the row rate, as the whole seconds of
/// ROS 2 exports), the run is spread evenly up to the next distinct stamp (the last run with the
/// spacing of the one before it). Malformed lines and rows without a stamp take the previous
/// entry's time plus the current spacing, so every entry keeps its place in file order.
#[must_use]
pub fn source_times(recording: &Recording, period_s: Option<f64>) -> Vec<f64> {
    let count = recording.entries.len();
    if let Some(period_s) = period_s {
        return (0..count).map(|k| k as f64 * period_s).collect();
    }
    // Stamps as recorded, gaps filled from the previous one.
    let raw: Vec<Option<f64>> = recording
        .entries
        .iter()
        .map(|e| e.as_ref().ok().and_then(|r| r.stamp_s))
        .collect();
    let mut times = vec![0.0; count];
    let mut spacing_s = 0.0;
    // Entries before the first stamp (a truncated first line, a units row) take that stamp, so
    // that pacing starts from the recording's own time.
    let mut start = raw.iter().position(Option::is_some).unwrap_or(count);
    let first_s = raw.get(start).copied().flatten().unwrap_or(0.0);
    times[..start].fill(first_s);
    while start < count {
        let Some(stamp) = raw[start] else {
            times[start] = if start == 0 {
                0.0
            } else {
                times[start - 1] + spacing_s
            };
            start += 1;
            continue;
        };
        // The run of entries sharing this stamp (or lacking one) up to the next distinct stamp.
        let mut end = start + 1;
        #[allow(clippy::float_cmp, reason = "equal recorded stamps define the run")]
        while end < count && raw[end].is_none_or(|s| s == stamp) {
            end += 1;
        }
        if let Some(next) = raw.get(end).copied().flatten()
            && next > stamp
        {
            spacing_s = (next - stamp) / (end - start) as f64;
        }
        for (k, time) in times[start..end].iter_mut().enumerate() {
            *time = stamp + k as f64 * spacing_s;
        }
        start = end;
    }
    times
}

#[cfg(test)]
#[allow(
    clippy::float_cmp,
    reason = "the spread stamps are exact binary fractions"
)]
mod tests {
    use super::*;

    #[test]
    fn equal_stamps_are_spread_to_the_next_second() {
        let text = "header.stamp.sec,shoulder_pan_joint.position,shoulder_lift_joint.position,elbow_joint.position,wrist_1_joint.position,wrist_2_joint.position,wrist_3_joint.position\n\
                    10,0,0,0,0,0,0\n10,0,0,0,0,0,0\n10,0,0,0,0,0,0\n10,0,0,0,0,0,0\n11,0,0,0,0,0,0\n11,0,0,0,0,0,0\n";
        let recording = read(text).expect("recognised");
        assert_eq!(recording.format, Format::Ros2);
        assert!(!recording.has_pose);
        let times = source_times(&recording, None);
        assert_eq!(times, [10.0, 10.25, 10.5, 10.75, 11.0, 11.25]);
        assert_eq!(source_times(&recording, Some(0.1))[3], 0.30000000000000004);
    }

    #[test]
    fn a_leading_line_without_stamp_takes_the_first_stamp() {
        let text = "time,q1,q2,q3,q4,q5,q6\nunits,rad,rad,rad,rad,rad,rad\n1700000000.0,0,0,0,0,0,0\n1700000000.5,0,0,0,0,0,0\n";
        let recording = read(text).expect("recognised");
        let times = source_times(&recording, None);
        assert_eq!(times, [1_700_000_000.0, 1_700_000_000.0, 1_700_000_000.5]);
    }

    #[test]
    fn rtde_space_separated_with_extra_columns() {
        let text = "timestamp target_q_0 actual_q_0 actual_q_1 actual_q_2 actual_q_3 actual_q_4 actual_q_5 actual_TCP_pose_0 actual_TCP_pose_1 actual_TCP_pose_2 actual_TCP_pose_3 actual_TCP_pose_4 actual_TCP_pose_5\n\
                    1.000 9 0.1 0.2 0.3 0.4 0.5 0.6 -0.8 0.4 0.4 0.1 2.0 0.0\n1.002 9 0.1 0.2 0.3 0.4 0.5 0.6 -0.8 0.4 0.4 0.1 2.0 0.0 extra\n";
        let recording = read(text).expect("recognised");
        assert_eq!(recording.format, Format::Rtde);
        let row = recording.entries[0].as_ref().expect("row");
        let message = row.to_message(1.0);
        assert_eq!(message["q"][0], json!(0.1));
        assert_eq!(message["measured"]["rx"], json!(0.1));
        let malformed = recording.entries[1].as_ref().expect_err("extra column");
        assert_eq!(malformed.line, 3);
    }

    #[test]
    fn named_columns_are_read_with_the_rows_line_numbers() {
        let text = "timestamp actual_current_0 payload robot_status_bits\n\n1.0 0.5 2.0 3\n1.002 x 2.0 7\n1.004 0.25 2.0\n";
        let table = read_columns(text, &["payload", "ACTUAL_CURRENT_0", "target_moment_0"])
            .expect("a header");
        assert_eq!(table.found, [true, true, false]);
        assert_eq!(
            table.rows,
            [
                (3, vec![Some(2.0), Some(0.5), None]),
                (4, vec![Some(2.0), None, None]),
                (5, vec![None, None, None]),
            ]
        );
    }

    #[test]
    fn line_numbers_and_text_survive_blank_lines_and_crlf() {
        let text = "\r\n\ntime,q1,q2,q3,q4,q5,q6\r\n\r\n1,0,0,0,0,0,0\r\n\n   \n, ,\r\n2,0,\"0\",0,0,0,0\r\n\r\n\r\n 3 , 0,0,0,0,0,zz";
        let recording = read(text).expect("recognised");
        let lines: Vec<u64> = recording
            .entries
            .iter()
            .map(|e| e.as_ref().map_or_else(|m| m.line, |r| r.line))
            .collect();
        assert_eq!(lines, [5, 8, 9, 12]);
        let malformed = recording.entries[1].as_ref().expect_err("3 columns");
        assert_eq!(malformed.text, ", ,");
        assert_eq!(malformed.problem, "3 columns, the header has 7");
        let quoted = recording.entries[2].as_ref().expect("row");
        assert_eq!(quoted.q[1], Cell::Text("\"0\"".to_owned()));
        let last = recording.entries[3].as_ref().expect("row");
        assert_eq!(
            (last.stamp_s, &last.q[5]),
            (Some(3.0), &Cell::Text("zz".to_owned()))
        );
    }

    #[test]
    fn white_space_runs_and_tabs_separate_cells() {
        let header =
            "timestamp\tactual_q_0 actual_q_1  actual_q_2 actual_q_3 actual_q_4 actual_q_5";
        let text = format!("{header}\n  1.5\t0.1   0.2 0.3 0.4 0.5 0.6  \n\n2.5 0.1 0.2\n");
        let recording = read(&text).expect("recognised");
        assert_eq!(recording.format, Format::Rtde);
        let row = recording.entries[0].as_ref().expect("row");
        assert_eq!((row.line, row.stamp_s), (2, Some(1.5)));
        assert_eq!(row.q[5], Cell::Number(0.6));
        let short = recording.entries[1].as_ref().expect_err("3 columns");
        assert_eq!((short.line, short.text.as_str()), (4, "2.5 0.1 0.2"));
    }

    #[test]
    fn text_cells_stay_text_and_quoted_lines_are_malformed() {
        let text = "time,q1,q2,q3,q4,q5,q6,x,y,z,qx,qy,qz,qw\n1,0,0,0,0,0,0,1,2,3,0,0,0,1\n2,0,0,0,0,0,zz,1,2,3,0,0,0,1\n\"3,0,0,0,0,0,0,1,2,3,0,0,\"\"1,5\"\",1\"\n";
        let recording = read(text).expect("recognised");
        assert_eq!(recording.format, Format::FmpyInputs);
        let row = recording.entries[1].as_ref().expect("row");
        assert_eq!(row.to_message(2.0)["q"][5], json!("zz"));
        assert!(recording.entries[2].is_err());
        assert!(matches!(
            read("a,b\n1,2\n"),
            Err(RecordingError::UnknownHeader { .. })
        ));
    }
}
