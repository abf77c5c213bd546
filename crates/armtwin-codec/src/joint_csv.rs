//! Joint-angle CSV in, FMPy-style pose CSV out.
//!
//! Input: a header naming `q1..qn` (any order, case-insensitive) and optionally `time`; other
//! columns are ignored, so a recording with measured poses beside the joints reads as is. A file
//! without a header is accepted when its first row is all numbers: `n` columns are `q1..qn`,
//! `n + 1` columns are `time, q1..qn`. Without a time column, time is the 0-based row index.
//! Output: `time,x,y,z,roll,pitch,yaw,qx,qy,qz,qw`, every number in its shortest round-trip form.

use std::io::{Read, Write};

use thiserror::Error;

use crate::PoseFields;

/// One row of joint angles.
#[derive(Debug, Clone, PartialEq)]
pub struct JointRow {
    /// 1-based line number in the file.
    pub line: u64,
    /// The row's time (s), or its 0-based index when the file has no time column.
    pub time_s: f64,
    /// Joint angles in file units.
    pub q: Vec<f64>,
}

/// Why a joint CSV cannot be read.
#[derive(Debug, Error)]
pub enum JointCsvError {
    /// The header lacks a required column.
    #[error("header: no column '{column}' (need q1..q{joint_count}, optionally time)")]
    MissingColumn {
        /// The column looked for.
        column: String,
        /// Joints of the model.
        joint_count: usize,
    },
    /// A headerless file has the wrong number of columns.
    #[error(
        "line {line}: {got} columns; without a header expected {joint_count} (q1..q{joint_count}) or {} (time, q1..q{joint_count})",
        joint_count + 1
    )]
    ColumnCount {
        /// 1-based line.
        line: u64,
        /// Columns found.
        got: usize,
        /// Joints of the model.
        joint_count: usize,
    },
    /// A cell is not a number.
    #[error("line {line}, column '{column}': '{text}' is not a number")]
    NotANumber {
        /// 1-based line.
        line: u64,
        /// Column name.
        column: String,
        /// The cell.
        text: String,
    },
    /// A row has fewer cells than the header.
    #[error("line {line}: row too short, no value for column '{column}'")]
    ShortRow {
        /// 1-based line.
        line: u64,
        /// The first missing column.
        column: String,
    },
    /// The file is empty.
    #[error("the file is empty")]
    Empty,
    /// The CSV layer failed (I/O or malformed quoting).
    #[error(transparent)]
    Csv(#[from] csv::Error),
}

/// Reads joint rows from a CSV.
pub struct JointCsvReader<R: Read> {
    records: csv::StringRecordsIntoIter<R>,
    /// The first data row when the file has no header.
    pending: Option<csv::StringRecord>,
    time_column: Option<usize>,
    q_columns: Vec<usize>,
    column_names: Vec<String>,
    row_index: u64,
}

impl<R: Read> JointCsvReader<R> {
    /// Opens a reader for an arm of `joint_count` joints and reads the header.
    pub fn new(input: R, joint_count: usize) -> Result<Self, JointCsvError> {
        let mut records = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(input)
            .into_records();
        let first = records.next().ok_or(JointCsvError::Empty)??;
        let all_numbers = first.iter().all(|cell| cell.parse::<f64>().is_ok());
        let (time_column, q_columns, column_names, pending) = if all_numbers {
            let time_column = match first.len() {
                n if n == joint_count => None,
                n if n == joint_count + 1 => Some(0),
                got => {
                    return Err(JointCsvError::ColumnCount {
                        line: 1,
                        got,
                        joint_count,
                    });
                }
            };
            let offset = usize::from(time_column.is_some());
            let mut names = Vec::new();
            if time_column.is_some() {
                names.push("time".to_owned());
            }
            names.extend((1..=joint_count).map(|j| format!("q{j}")));
            (
                time_column,
                (offset..offset + joint_count).collect(),
                names,
                Some(first),
            )
        } else {
            let names: Vec<String> = first.iter().map(str::to_owned).collect();
            let find = |wanted: &str| names.iter().position(|n| n.eq_ignore_ascii_case(wanted));
            let time_column = find("time");
            let q_columns = (1..=joint_count)
                .map(|j| {
                    let column = format!("q{j}");
                    find(&column).ok_or(JointCsvError::MissingColumn {
                        column,
                        joint_count,
                    })
                })
                .collect::<Result<Vec<_>, _>>()?;
            (time_column, q_columns, names, None)
        };
        Ok(Self {
            records,
            pending,
            time_column,
            q_columns,
            column_names,
            row_index: 0,
        })
    }

    fn cell(
        &self,
        record: &csv::StringRecord,
        line: u64,
        column: usize,
    ) -> Result<f64, JointCsvError> {
        let name = || self.column_names.get(column).cloned().unwrap_or_default();
        let text = record.get(column).ok_or_else(|| JointCsvError::ShortRow {
            line,
            column: name(),
        })?;
        text.parse().map_err(|_| JointCsvError::NotANumber {
            line,
            column: name(),
            text: text.to_owned(),
        })
    }

    fn row(&mut self, record: &csv::StringRecord) -> Result<JointRow, JointCsvError> {
        let line = record
            .position()
            .map_or(self.row_index + 1, csv::Position::line);
        let time_s = match self.time_column {
            Some(column) => self.cell(record, line, column)?,
            None => self.row_index as f64,
        };
        let q = self
            .q_columns
            .iter()
            .map(|&column| self.cell(record, line, column))
            .collect::<Result<Vec<_>, _>>()?;
        self.row_index += 1;
        Ok(JointRow { line, time_s, q })
    }
}

impl<R: Read> Iterator for JointCsvReader<R> {
    type Item = Result<JointRow, JointCsvError>;

    fn next(&mut self) -> Option<Self::Item> {
        let record = match self.pending.take() {
            Some(record) => record,
            None => match self.records.next()? {
                Ok(record) => record,
                Err(e) => return Some(Err(e.into())),
            },
        };
        Some(self.row(&record))
    }
}

/// Writes the FMPy-style pose CSV `time,x,y,z,roll,pitch,yaw,qx,qy,qz,qw`.
pub struct PoseCsvWriter<W: Write> {
    output: W,
}

impl<W: Write> PoseCsvWriter<W> {
    /// Writes the header.
    pub fn new(mut output: W) -> std::io::Result<Self> {
        writeln!(output, "time,{}", PoseFields::NAMES.join(","))?;
        Ok(Self { output })
    }

    /// Writes one row.
    pub fn write(&mut self, time_s: f64, pose: &PoseFields) -> std::io::Result<()> {
        write!(self.output, "{time_s:?}")?;
        for value in pose.values() {
            write!(self.output, ",{value:?}")?;
        }
        writeln!(self.output)
    }

    /// Flushes and returns the writer.
    pub fn finish(mut self) -> std::io::Result<W> {
        self.output.flush()?;
        Ok(self.output)
    }
}
