//! The service's snapshot file: what of each twin outlives the process ([`TwinRecord`]), as JSON
//! in `<state_dir>/twin-state.json`.
//!
//! Owns the file format, its atomic replacement (a temporary file beside it, `fsync`, `rename`,
//! `fsync` of the folder: a crash leaves the old snapshot or the new one, never half of one) and
//! the refusal of a file that is damaged or was written by another armtwin format or service
//! (it is moved aside, named with the time it was refused, and the service starts fresh). What a
//! record means is the core's ([`armtwin_core::pipeline::Pipeline::restore`]).

use std::fs::{self, File};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use thiserror::Error;

use armtwin_core::kinematics::TcpOffset;
use armtwin_core::metrics::{CumulativeParts, HistoryRow, METRIC_COUNT, SecondTotals};
use armtwin_core::model::MountingDeltas;
use armtwin_core::pipeline::{Alarms, AppliedModel, TwinRecord};

/// The format the file declares; a file of another format is refused.
pub const SNAPSHOT_FORMAT: &str = "armtwin-twin-state/v1";

/// The file's name in the state folder.
pub const SNAPSHOT_FILE: &str = "twin-state.json";

/// Largest snapshot file read (a fleet of thousands of robots is a few megabytes): a larger one
/// is refused unread rather than held in memory.
const MAX_SNAPSHOT_BYTES: u64 = 256 * 1024 * 1024;

/// Why a snapshot was not written or not taken.
#[derive(Debug, Error)]
pub enum SnapshotError {
    /// The file or its folder cannot be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not a snapshot armtwin can read (damaged, truncated, not JSON).
    #[error("{path} is not a readable snapshot: {problem}")]
    Corrupt {
        /// The file.
        path: String,
        /// What is wrong.
        problem: String,
    },
    /// The file is a snapshot of another format, service or fleet.
    #[error("{path} is a foreign snapshot: {problem}")]
    Foreign {
        /// The file.
        path: String,
        /// What does not match.
        problem: String,
    },
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SnapshotFile {
    format: String,
    key_prefix: String,
    robots: Vec<RecordJson>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RecordJson {
    robot: String,
    arm: String,
    epoch: u64,
    paired: u64,
    unpaired: u64,
    rejected: u64,
    next_pose_seq: u64,
    last_gateway_seq: Option<u64>,
    cumulative: CumulativeJson,
    /// Position alarm, angle alarm: the file's order.
    alarms_active: [bool; 2],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    applied: Option<AppliedJson>,
    /// The history's minutes, oldest first.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    history_minutes: Vec<MinuteJson>,
}

/// A minute of the history, an array: `[t, n, [position, angle] sums, [position, angle] sums
/// of squares, [position, angle] maxima]`.
#[derive(Debug, Serialize, Deserialize)]
struct MinuteJson(i64, u64, [f64; 2], [f64; 2], [f64; 2]);

impl MinuteJson {
    fn new(row: &HistoryRow) -> Self {
        let totals = &row.totals;
        Self(
            row.second,
            totals.n,
            totals.sums,
            totals.sums_of_squares,
            totals.maxima,
        )
    }

    fn into_row(self) -> HistoryRow {
        let Self(second, n, sums, sums_of_squares, maxima) = self;
        HistoryRow {
            second,
            totals: SecondTotals {
                n,
                sums,
                sums_of_squares,
                maxima,
            },
        }
    }
}

/// [`AppliedModel`]: the `calibration.conf` deltas and the tool as the pendant writes it.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct AppliedJson {
    delta_theta_rad: [f64; 6],
    delta_a_m: [f64; 6],
    delta_d_m: [f64; 6],
    delta_alpha_rad: [f64; 6],
    /// `[x, y, z, rx, ry, rz]` (m, rad): the TCP in the flange frame.
    tcp: [f64; 6],
}

impl AppliedJson {
    fn new(applied: &AppliedModel) -> Self {
        let deltas = &applied.deltas;
        let tool = &applied.tool;
        let [x, y, z] = tool.position_m;
        let [rx, ry, rz] = tool.rotation_vector_rad;
        Self {
            delta_theta_rad: deltas.delta_theta_rad,
            delta_a_m: deltas.delta_a_m,
            delta_d_m: deltas.delta_d_m,
            delta_alpha_rad: deltas.delta_alpha_rad,
            tcp: [x, y, z, rx, ry, rz],
        }
    }

    fn into_applied(self) -> AppliedModel {
        let [x, y, z, rx, ry, rz] = self.tcp;
        AppliedModel {
            deltas: MountingDeltas {
                delta_theta_rad: self.delta_theta_rad,
                delta_a_m: self.delta_a_m,
                delta_d_m: self.delta_d_m,
                delta_alpha_rad: self.delta_alpha_rad,
            },
            tool: TcpOffset {
                position_m: [x, y, z],
                rotation_vector_rad: [rx, ry, rz],
            },
        }
    }
}

/// [`CumulativeParts`]; maxima are absent for an empty set (JSON has no `-inf`).
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CumulativeJson {
    n: u64,
    sums: [[f64; 2]; METRIC_COUNT],
    sums_of_squares: [[f64; 2]; METRIC_COUNT],
    maxima: Option<[f64; METRIC_COUNT]>,
}

impl RecordJson {
    fn new(record: &TwinRecord) -> Self {
        let parts = &record.cumulative;
        Self {
            robot: record.robot.clone(),
            arm: record.arm.clone(),
            epoch: record.epoch,
            paired: record.paired,
            unpaired: record.unpaired,
            rejected: record.rejected,
            next_pose_seq: record.next_pose_seq,
            last_gateway_seq: record.last_gateway_seq,
            cumulative: CumulativeJson {
                n: parts.n,
                sums: parts.sums,
                sums_of_squares: parts.sums_of_squares,
                maxima: (parts.n > 0).then_some(parts.maxima),
            },
            alarms_active: [record.alarms_active.position, record.alarms_active.angle],
            applied: record.applied.as_ref().map(AppliedJson::new),
            history_minutes: record.history_minutes.iter().map(MinuteJson::new).collect(),
        }
    }

    fn into_record(self) -> Result<TwinRecord, String> {
        let [position, angle] = self.alarms_active;
        let cumulative = self.cumulative;
        let maxima = match (cumulative.n, cumulative.maxima) {
            (0, _) => [f64::NEG_INFINITY; METRIC_COUNT],
            (_, Some(maxima)) => maxima,
            (n, None) => {
                return Err(format!(
                    "robot '{}': {n} samples without maxima",
                    self.robot
                ));
            }
        };
        Ok(TwinRecord {
            robot: self.robot,
            arm: self.arm,
            epoch: self.epoch,
            paired: self.paired,
            unpaired: self.unpaired,
            rejected: self.rejected,
            next_pose_seq: self.next_pose_seq,
            last_gateway_seq: self.last_gateway_seq,
            cumulative: CumulativeParts {
                n: cumulative.n,
                sums: cumulative.sums,
                sums_of_squares: cumulative.sums_of_squares,
                maxima,
            },
            alarms_active: Alarms { position, angle },
            applied: self.applied.map(AppliedJson::into_applied),
            history_minutes: self
                .history_minutes
                .into_iter()
                .map(MinuteJson::into_row)
                .collect(),
        })
    }
}

/// The snapshot file of one service.
#[derive(Debug, Clone)]
pub struct SnapshotStore {
    path: PathBuf,
    key_prefix: String,
}

impl SnapshotStore {
    /// The store in `state_dir` of the service with `key_prefix` (the folder is created on the
    /// first write).
    #[must_use]
    pub fn new(state_dir: &Path, key_prefix: &str) -> Self {
        Self {
            path: state_dir.join(SNAPSHOT_FILE),
            key_prefix: key_prefix.to_owned(),
        }
    }

    /// The snapshot file's path.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn io(path: &Path) -> impl FnOnce(std::io::Error) -> SnapshotError + '_ {
        move |source| SnapshotError::Io {
            path: path.display().to_string(),
            source,
        }
    }

    /// The file's bytes for `records`.
    #[must_use]
    pub fn encode(&self, records: &[TwinRecord]) -> Vec<u8> {
        let file = SnapshotFile {
            format: SNAPSHOT_FORMAT.to_owned(),
            key_prefix: self.key_prefix.clone(),
            robots: records.iter().map(RecordJson::new).collect(),
        };
        // Every field is a number, a string or a bool: serialising cannot fail.
        serde_json::to_vec_pretty(&file).unwrap_or_default()
    }

    /// Replaces the snapshot with `records`, atomically.
    pub fn save(&self, records: &[TwinRecord]) -> Result<(), SnapshotError> {
        let dir = self.path.parent().unwrap_or_else(|| Path::new("."));
        fs::create_dir_all(dir).map_err(Self::io(dir))?;
        let temporary = self.path.with_extension("json.partial");
        let bytes = self.encode(records);
        let mut file = File::create(&temporary).map_err(Self::io(&temporary))?;
        file.write_all(&bytes).map_err(Self::io(&temporary))?;
        file.sync_all().map_err(Self::io(&temporary))?;
        drop(file);
        fs::rename(&temporary, &self.path).map_err(Self::io(&self.path))?;
        // The rename is durable once the folder's entry is.
        File::open(dir)
            .and_then(|folder| folder.sync_all())
            .map_err(Self::io(dir))?;
        Ok(())
    }

    /// The records of `bytes`, a snapshot file's content.
    pub fn decode(&self, bytes: &[u8]) -> Result<Vec<TwinRecord>, SnapshotError> {
        let path = self.path.display().to_string();
        let corrupt = |problem: String| SnapshotError::Corrupt {
            path: path.clone(),
            problem,
        };
        let value: serde_json::Value =
            serde_json::from_slice(bytes).map_err(|e| corrupt(e.to_string()))?;
        // The format is read first, so that a file of another version is called foreign, not
        // damaged, whatever its other fields.
        let format = value.get("format").and_then(serde_json::Value::as_str);
        if format != Some(SNAPSHOT_FORMAT) {
            return Err(SnapshotError::Foreign {
                path,
                problem: format!(
                    "format {}, this armtwin reads {SNAPSHOT_FORMAT}",
                    format.map_or_else(|| "missing".to_owned(), |f| format!("'{f}'"))
                ),
            });
        }
        let file: SnapshotFile =
            serde_json::from_value(value).map_err(|e| corrupt(e.to_string()))?;
        if file.key_prefix != self.key_prefix {
            return Err(SnapshotError::Foreign {
                path,
                problem: format!(
                    "written by a service with key prefix '{}', this one's is '{}'",
                    file.key_prefix, self.key_prefix
                ),
            });
        }
        let mut robots: Vec<&str> = file.robots.iter().map(|r| r.robot.as_str()).collect();
        robots.sort_unstable();
        if let Some([robot, _]) = robots.windows(2).find(|pair| pair[0] == pair[1]) {
            return Err(corrupt(format!("robot '{robot}' is recorded twice")));
        }
        file.robots
            .into_iter()
            .map(RecordJson::into_record)
            .collect::<Result<Vec<_>, _>>()
            .map_err(corrupt)
    }

    /// The records of the snapshot file; `None` when there is none.
    pub fn load(&self) -> Result<Option<Vec<TwinRecord>>, SnapshotError> {
        let size = match fs::metadata(&self.path) {
            Ok(metadata) => metadata.len(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(Self::io(&self.path)(e)),
        };
        if size > MAX_SNAPSHOT_BYTES {
            return Err(SnapshotError::Corrupt {
                path: self.path.display().to_string(),
                problem: format!("{size} bytes, more than a snapshot's {MAX_SNAPSHOT_BYTES}"),
            });
        }
        let bytes = fs::read(&self.path).map_err(Self::io(&self.path))?;
        self.decode(&bytes).map(Some)
    }

    /// Moves a refused snapshot aside, to `twin-state.json.refused-<unix time s>`, so that the
    /// next snapshot does not overwrite what an operator may want to inspect; returns its name.
    pub fn set_aside(&self) -> Result<PathBuf, SnapshotError> {
        let stamp_s = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        let aside = self.path.with_extension(format!("json.refused-{stamp_s}"));
        fs::rename(&self.path, &aside).map_err(Self::io(&self.path))?;
        Ok(aside)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(robot: &str, n: u64) -> TwinRecord {
        TwinRecord {
            robot: robot.to_owned(),
            arm: "ur10e".to_owned(),
            epoch: 1,
            paired: n,
            unpaired: 2,
            rejected: 3,
            next_pose_seq: 41,
            last_gateway_seq: Some(40),
            cumulative: CumulativeParts {
                n,
                sums: [[0.1, 1e-18]; METRIC_COUNT],
                sums_of_squares: [[0.01, -1e-19]; METRIC_COUNT],
                maxima: if n == 0 {
                    [f64::NEG_INFINITY; METRIC_COUNT]
                } else {
                    [0.3; METRIC_COUNT]
                },
            },
            alarms_active: Alarms {
                position: true,
                angle: false,
            },
            applied: None,
            history_minutes: Vec::new(),
        }
    }

    #[test]
    fn records_survive_the_file_bit_for_bit_and_replace_it_whole() {
        let dir = tempfile::tempdir().expect("temporary folder");
        let store = SnapshotStore::new(&dir.path().join("state"), "twin");
        assert!(store.load().expect("no file is no snapshot").is_none());
        let mut calibrated = record("c/r3", 5);
        calibrated.applied = Some(AppliedModel {
            deltas: MountingDeltas {
                delta_theta_rad: [1e-3, -2e-4, 0.1 + 0.2, 0.0, -0.0, 5e-324],
                delta_a_m: [0.0, 4e-4, -1e-5, 0.0, 0.0, 0.0],
                delta_d_m: [0.0, 123.456_789, -98.7, 1e-6, 0.0, 0.0],
                delta_alpha_rad: [0.0, 1e-3, 0.0, -1e-3, 0.0, 0.0],
            },
            tool: TcpOffset {
                position_m: [0.01, -0.02, 0.15],
                rotation_vector_rad: [0.0, 3.0, 0.1],
            },
        });
        calibrated.history_minutes = vec![
            HistoryRow {
                second: -120,
                totals: SecondTotals {
                    n: 3,
                    sums: [0.1 + 0.2, 5e-324],
                    sums_of_squares: [1e-300, 0.0],
                    maxima: [0.2, 1e-9],
                },
            },
            HistoryRow {
                second: 1_764_000_000,
                totals: SecondTotals {
                    n: 30_000,
                    sums: [12.345_678_901_234_567, 0.25],
                    sums_of_squares: [0.007, 1e-12],
                    maxima: [0.004_999, 3e-3],
                },
            },
        ];
        let records = vec![record("a/r1", 7), record("b/r2", 0), calibrated];
        store.save(&records).expect("written");
        assert_eq!(store.load().expect("readable"), Some(records.clone()));
        store.save(&records[..1]).expect("replaced");
        assert_eq!(store.load().expect("readable"), Some(records[..1].to_vec()));
        let names: Vec<_> = fs::read_dir(dir.path().join("state"))
            .expect("folder")
            .map(|entry| entry.expect("entry").file_name())
            .collect();
        assert_eq!(names, [SNAPSHOT_FILE], "no temporary file is left behind");
    }

    #[test]
    fn damaged_and_foreign_files_are_refused_and_set_aside() {
        let dir = tempfile::tempdir().expect("temporary folder");
        let store = SnapshotStore::new(dir.path(), "twin");
        let good = store.encode(&[record("r1", 7)]);
        let text = String::from_utf8(good.clone()).expect("JSON is text");
        let cases: [(&str, Vec<u8>); 5] = [
            ("not a readable snapshot", good[..good.len() / 2].to_vec()),
            (
                "not a readable snapshot",
                text.replace("\"paired\"", "\"paired_x\"").into_bytes(),
            ),
            (
                "foreign snapshot: format 'armtwin-twin-state/v0'",
                text.replace(SNAPSHOT_FORMAT, "armtwin-twin-state/v0")
                    .into_bytes(),
            ),
            (
                "foreign snapshot: format missing",
                b"{\"robots\": []}".to_vec(),
            ),
            (
                "key prefix 'plant'",
                SnapshotStore::new(dir.path(), "plant").encode(&[record("r1", 7)]),
            ),
        ];
        for (expected, bytes) in cases {
            fs::write(store.path(), &bytes).expect("written");
            let error = store.load().expect_err(expected);
            assert!(error.to_string().contains(expected), "{error}");
            let aside = store.set_aside().expect("moved");
            assert!(!store.path().exists());
            assert_eq!(fs::read(&aside).expect("kept"), bytes);
            fs::remove_file(aside).expect("removed");
        }
        let twice = text.replace("\"robots\": [", "\"robots\": [{\"robot\": \"r1\", \"arm\": \"ur10e\", \"epoch\": 0, \"paired\": 0, \"unpaired\": 0, \"rejected\": 0, \"next_pose_seq\": 0, \"last_gateway_seq\": null, \"cumulative\": {\"n\": 0, \"sums\": [[0,0],[0,0],[0,0],[0,0],[0,0],[0,0],[0,0],[0,0],[0,0]], \"sums_of_squares\": [[0,0],[0,0],[0,0],[0,0],[0,0],[0,0],[0,0],[0,0],[0,0]], \"maxima\": null}, \"alarms_active\": [false, false]},");
        let error = store.decode(twice.as_bytes()).expect_err("twice");
        assert!(error.to_string().contains("recorded twice"), "{error}");
    }
}
