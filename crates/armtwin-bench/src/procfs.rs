//! What Linux tells about another process: resident memory and CPU time, from `/proc/<pid>`.
//!
//! Owns the parsing of `/proc/<pid>/status` and `/proc/<pid>/stat`; knows nothing of Zenoh.

use std::fs;

use thiserror::Error;

/// Clock ticks per second of `/proc/<pid>/stat` times (`USER_HZ`, 100 on every Linux ABI this
/// runs on).
const USER_HZ: f64 = 100.0;

/// Why a process could not be read.
#[derive(Debug, Error)]
pub enum ProcError {
    /// The file could not be read (the process is gone, or this is not Linux).
    #[error("/proc/{pid}/{file}: {source}")]
    Read {
        /// The process.
        pid: u32,
        /// `status` or `stat`.
        file: &'static str,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file did not hold the expected field.
    #[error("/proc/{pid}/{file}: no {field}")]
    Field {
        /// The process.
        pid: u32,
        /// `status` or `stat`.
        file: &'static str,
        /// The field looked for.
        field: &'static str,
    },
}

fn read(pid: u32, file: &'static str) -> Result<String, ProcError> {
    fs::read_to_string(format!("/proc/{pid}/{file}")).map_err(|source| ProcError::Read {
        pid,
        file,
        source,
    })
}

/// Resident set size (KiB): `VmRSS` of `/proc/<pid>/status`.
pub fn rss_kib(pid: u32) -> Result<u64, ProcError> {
    let status = read(pid, "status")?;
    status
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse().ok())
        .ok_or(ProcError::Field {
            pid,
            file: "status",
            field: "VmRSS",
        })
}

/// CPU time (s) the process used so far, user plus system, all threads.
pub fn cpu_s(pid: u32) -> Result<f64, ProcError> {
    let stat = read(pid, "stat")?;
    // Fields after the command name, which is in parentheses and may contain spaces.
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    // utime and stime are fields 14 and 15 of the whole line, 12 and 13 after the name.
    let ticks = |index: usize| fields.get(index).and_then(|v| v.parse::<u64>().ok());
    match (ticks(11), ticks(12)) {
        (Some(user), Some(system)) => Ok((user + system) as f64 / USER_HZ),
        _ => Err(ProcError::Field {
            pid,
            file: "stat",
            field: "utime/stime",
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_this_process() {
        let pid = std::process::id();
        assert!(rss_kib(pid).expect("rss") > 0);
        assert!(cpu_s(pid).expect("cpu") >= 0.0);
    }
}
