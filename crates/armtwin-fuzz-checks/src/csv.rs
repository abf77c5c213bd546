//! Joint-angle CSV (`armtwin validate`) and recordings (`armtwin replay`) as people hand them in:
//! every row read has one angle per joint and line numbers that never go back; a recording gives
//! every entry a source time and a payload; nothing panics.

use armtwin_codec::joint_csv::JointCsvReader;
use armtwin_codec::recording;

/// Runs every check of this decoder on one input; panics on a broken invariant.
pub fn check(bytes: &[u8]) {
    joint_csv(bytes, 6);
    joint_csv(bytes, 2);
    if let Ok(text) = std::str::from_utf8(bytes) {
        recording(text);
    }
}

fn joint_csv(bytes: &[u8], joint_count: usize) {
    let Ok(reader) = JointCsvReader::new(bytes, joint_count) else {
        return;
    };
    let mut last_line = 0;
    for row in reader {
        let Ok(row) = row else {
            continue;
        };
        assert_eq!(row.q.len(), joint_count);
        // Not strictly: a bare CR ends a record too (the csv crate's rule) without starting a
        // line, so two rows can share one.
        assert!(row.line >= last_line, "line {} after {last_line}", row.line);
        last_line = row.line;
    }
}

fn recording(text: &str) {
    let Ok(recording) = recording::read(text) else {
        return;
    };
    for period_s in [None, Some(0.002)] {
        let times = recording::source_times(&recording, period_s);
        assert_eq!(times.len(), recording.entries.len());
    }
    for entry in &recording.entries {
        let _ = recording::payload(entry, 1.0);
    }
}
