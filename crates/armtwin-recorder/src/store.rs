//! The recorder's writer thread: incidents in, MCAP files out, named
//! `<dir>/<robot>/<UTC time>-<trigger>.mcap`, and each outcome counted and handed back
//! ([`Outcome`]) for the events.
//!
//! Fair to every robot: one robot has at most one incident waiting (the queue holds
//! [`QUEUE`] robots' incidents), and retention takes a robot's own oldest files past its share
//! (`robot_max_files`, `robot_max_bytes`), then, past the fleet's (`max_files`, `max_bytes`), the
//! oldest of the robot that holds the most. A robot that sets incidents off without pause fills
//! its own share, never another's.
//!
//! The sample path only hands an incident over ([`IncidentSender::send`], never blocking: a full
//! queue drops it, counted); every file operation is this thread's. A write that fails (a full
//! disk) removes what it left, is counted, and the thread goes on.

use std::collections::{BTreeMap, HashSet};
use std::fmt::Write as _;
use std::fs;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use tracing::{info, warn};

use super::incident::{Incident, write_mcap};

/// Incidents waiting for the writer thread, one robot's at most one; more are dropped (and
/// counted).
pub const QUEUE: usize = 16;

/// Where files go and how many are kept.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StoreSettings {
    /// `[recorder] dir`.
    pub dir: PathBuf,
    /// `[recorder] max_files`: files kept in `dir`, every robot's together.
    pub max_files: usize,
    /// `[recorder] max_bytes`: bytes kept in `dir`.
    pub max_bytes: u64,
    /// `[recorder] robot_max_files`: files kept of one robot.
    pub robot_max_files: usize,
    /// `[recorder] robot_max_bytes`: bytes kept of one robot.
    pub robot_max_bytes: u64,
}

/// The recorder's counts, for `/metrics` and the service's totals.
#[derive(Debug, Default)]
pub struct StoreCounters {
    /// Files written.
    pub files: AtomicU64,
    /// Bytes of the files written.
    pub bytes: AtomicU64,
    /// Writes that failed.
    pub failures: AtomicU64,
    /// Incidents dropped because the queue was full or the thread gone.
    pub dropped: AtomicU64,
    /// Files removed by retention.
    pub removed: AtomicU64,
}

/// How an incident's file turned out.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// Written.
    Recorded {
        /// Robot id.
        robot: String,
        /// What set it off.
        trigger: &'static str,
        /// The file.
        path: PathBuf,
        /// Its size.
        bytes: u64,
        /// Source time (s) it spans.
        from_s: f64,
        /// The same, its end.
        until_s: f64,
        /// Messages in it.
        messages: u64,
        /// Time it took to write (s).
        write_s: f64,
    },
    /// Not written.
    Failed {
        /// Robot id.
        robot: String,
        /// What set it off.
        trigger: &'static str,
        /// The file it would have been.
        path: PathBuf,
        /// Why.
        error: String,
    },
}

/// What the writer thread is handed.
#[derive(Debug)]
enum Job {
    Write(Box<Incident>),
    /// Stop once what came before is written.
    Stop,
}

/// The robots with an incident in the queue (at most [`QUEUE`] of them).
type Waiting = Arc<Mutex<HashSet<String>>>;

/// Hands incidents to the writer thread.
#[derive(Debug, Clone)]
pub struct IncidentSender {
    queue: SyncSender<Job>,
    waiting: Waiting,
    counters: Arc<StoreCounters>,
}

impl IncidentSender {
    /// Queues `incident` for writing; `false` (counted as dropped) if its robot has one waiting
    /// already or the queue is full.
    pub fn send(&self, incident: Incident) -> bool {
        let (robot, trigger) = (incident.robot.clone(), incident.trigger.kind);
        let mut waiting = self.waiting.lock().unwrap_or_else(PoisonError::into_inner);
        let why = if waiting.contains(&robot) {
            "the robot has an incident waiting to be written already"
        } else {
            match self.queue.try_send(Job::Write(Box::new(incident))) {
                Ok(()) => {
                    waiting.insert(robot);
                    return true;
                }
                Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                    "the recorder's queue is full"
                }
            }
        };
        drop(waiting);
        self.counters.dropped.fetch_add(1, Ordering::Relaxed);
        warn!(robot, trigger, "{why}: incident not written");
        false
    }

    /// Asks the writer thread to stop once it has written what it was handed (waits for room
    /// in the queue).
    pub fn stop(&self) {
        // A thread already gone has nothing left to write.
        let _ = self.queue.send(Job::Stop);
    }

    /// The counts.
    #[must_use]
    pub fn counters(&self) -> &Arc<StoreCounters> {
        &self.counters
    }
}

/// Starts the writer thread; it ends once every sender is dropped and the queue is written.
/// `announce` is called on it with each outcome.
pub fn spawn(
    settings: StoreSettings,
    announce: impl Fn(&Outcome) + Send + 'static,
) -> std::io::Result<(IncidentSender, JoinHandle<()>)> {
    let (queue, received) = sync_channel(QUEUE);
    let counters = Arc::new(StoreCounters::default());
    let waiting = Waiting::default();
    let thread_counters = Arc::clone(&counters);
    let thread_waiting = Arc::clone(&waiting);
    let handle = std::thread::Builder::new()
        .name("armtwin-recorder".to_owned())
        .spawn(move || {
            run(
                &settings,
                &received,
                &thread_waiting,
                &thread_counters,
                &announce,
            );
        })?;
    Ok((
        IncidentSender {
            queue,
            waiting,
            counters,
        },
        handle,
    ))
}

fn run(
    settings: &StoreSettings,
    received: &Receiver<Job>,
    waiting: &Waiting,
    counters: &StoreCounters,
    announce: &dyn Fn(&Outcome),
) {
    while let Ok(Job::Write(incident)) = received.recv() {
        waiting
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .remove(&incident.robot);
        let outcome = write(settings, &incident);
        match &outcome {
            Outcome::Recorded { path, bytes, .. } => {
                counters.files.fetch_add(1, Ordering::Relaxed);
                counters.bytes.fetch_add(*bytes, Ordering::Relaxed);
                info!(robot = incident.robot, trigger = incident.trigger.kind, path = %path.display(), bytes, "incident recorded");
                let removed = prune(settings);
                counters.removed.fetch_add(removed, Ordering::Relaxed);
            }
            Outcome::Failed { path, error, .. } => {
                counters.failures.fetch_add(1, Ordering::Relaxed);
                warn!(robot = incident.robot, trigger = incident.trigger.kind, path = %path.display(), error, "incident not recorded");
            }
        }
        announce(&outcome);
    }
}

/// Writes `incident` under `settings.dir` (through a `.part` file renamed when complete).
#[must_use]
pub fn write(settings: &StoreSettings, incident: &Incident) -> Outcome {
    let path = settings.dir.join(file_name(incident));
    let started = Instant::now();
    let part = path.with_extension("mcap.part");
    let written = (|| -> Result<(u64, u64), String> {
        if let Some(parent) = path.parent() {
            fs::create_dir_all(parent).map_err(|e| e.to_string())?;
        }
        let file = fs::File::create(&part).map_err(|e| e.to_string())?;
        let messages = write_mcap(BufWriter::new(&file), incident).map_err(|e| with_causes(&e))?;
        file.sync_all().map_err(|e| e.to_string())?;
        fs::rename(&part, &path).map_err(|e| e.to_string())?;
        let bytes = fs::metadata(&path).map_err(|e| e.to_string())?.len();
        Ok((bytes, messages))
    })();
    match written {
        Ok((bytes, messages)) => Outcome::Recorded {
            robot: incident.robot.clone(),
            trigger: incident.trigger.kind,
            path,
            bytes,
            from_s: incident.from_s,
            until_s: incident.until_s,
            messages,
            write_s: started.elapsed().as_secs_f64(),
        },
        Err(error) => {
            // What a full disk left behind goes too; there may be nothing to remove.
            let _ = fs::remove_file(&part);
            Outcome::Failed {
                robot: incident.robot.clone(),
                trigger: incident.trigger.kind,
                path,
                error,
            }
        }
    }
}

/// `error: its cause: …`: the MCAP writer's own message does not name the I/O error under it.
pub fn with_causes(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut cause = error.source();
    while let Some(next) = cause {
        let _ = write!(text, ": {next}");
        cause = next.source();
    }
    text
}

/// `<robot directory>/<UTC time>-<trigger>.mcap`, relative to the recorder's directory.
#[must_use]
pub fn file_name(incident: &Incident) -> PathBuf {
    Path::new(&robot_directory(&incident.robot)).join(format!(
        "{}-{}.mcap",
        utc_stamp(incident.trigger.at),
        incident.trigger.kind
    ))
}

/// Longest robot directory name: well inside every file system's 255 bytes.
const MAX_DIRECTORY_BYTES: usize = 120;

/// A robot id as one directory name: letters, digits, `-` and `_` as they are, every other byte
/// `%XX` (so `/`, `.` and `..` cannot climb out, and two ids never share a directory); a long
/// one is cut and ends with a hash of the whole id.
#[must_use]
pub fn robot_directory(robot: &str) -> String {
    let mut name = String::with_capacity(robot.len());
    for byte in robot.bytes() {
        if byte.is_ascii_alphanumeric() || byte == b'-' || byte == b'_' {
            name.push(char::from(byte));
        } else {
            let _ = write!(name, "%{byte:02X}");
        }
    }
    if name.len() > MAX_DIRECTORY_BYTES {
        // FNV-1a: stable across builds and platforms.
        let hash = robot.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |hash, byte| {
            (hash ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3)
        });
        let mut cut = MAX_DIRECTORY_BYTES - 17;
        while !name.is_char_boundary(cut) {
            cut -= 1;
        }
        name.truncate(cut);
        let _ = write!(name, "~{hash:016x}");
    }
    name
}

/// `YYYYMMDDTHHMMSS.mmmZ` of a wall-clock time (UTC): sorts as it happened.
#[must_use]
pub fn utc_stamp(at: SystemTime) -> String {
    let since = at.duration_since(UNIX_EPOCH).unwrap_or_default();
    let secs = since.as_secs();
    let (days, day_s) = (secs / 86_400, secs % 86_400);
    let (year, month, day) = civil_from_days(i64::try_from(days).unwrap_or(i64::MAX));
    format!(
        "{year:04}{month:02}{day:02}T{:02}{:02}{:02}.{:03}Z",
        day_s / 3600,
        day_s / 60 % 60,
        day_s % 60,
        since.subsec_millis()
    )
}

/// The proleptic Gregorian date of a day count since 1970-01-01 (Howard Hinnant's algorithm).
fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    let (month, day) = (u32::try_from(month), u32::try_from(day));
    (year, month.unwrap_or(1), day.unwrap_or(1))
}

/// The recorder's files under `dir` (one directory per robot), oldest first by name's time.
#[must_use]
pub fn files(dir: &Path) -> Vec<(PathBuf, u64)> {
    let mut found = Vec::new();
    let Ok(robots) = fs::read_dir(dir) else {
        return found;
    };
    for robot in robots.flatten() {
        mcap_files_in(&robot.path(), &mut found);
    }
    found.sort_by(|a, b| a.0.file_name().cmp(&b.0.file_name()));
    found
}

/// Adds the `.mcap` files of one robot's directory to `found`, with their sizes (folders and
/// symbolic links left out).
fn mcap_files_in(robot_dir: &Path, found: &mut Vec<(PathBuf, u64)>) {
    let Ok(entries) = fs::read_dir(robot_dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|ext| ext == "mcap")
            && let Ok(metadata) = entry.metadata()
            && metadata.is_file()
        {
            found.push((path, metadata.len()));
        }
    }
}

/// The most files [`robot_files`] lists: retention keeps far fewer by default.
pub const MAX_LISTED: usize = 10_000;

/// Robot `robot`'s files under `dir` (their names in its directory, and sizes), oldest first;
/// at most [`MAX_LISTED`] of them, the newest kept. `robot` is untrusted: it names a directory only
/// through [`robot_directory`], so it cannot climb out of `dir`.
#[must_use]
pub fn robot_files(dir: &Path, robot: &str) -> Vec<(String, u64)> {
    let mut paths = Vec::new();
    mcap_files_in(&dir.join(robot_directory(robot)), &mut paths);
    let mut found: Vec<(String, u64)> = paths
        .into_iter()
        .filter_map(|(path, bytes)| Some((path.file_name()?.to_str()?.to_owned(), bytes)))
        .collect();
    found.sort();
    let cut = found.len().saturating_sub(MAX_LISTED);
    found.drain(..cut);
    found
}

/// Robot `robot`'s file `name` under `dir`, and its size, if [`robot_files`] lists it: a name
/// that is not one of the listing's never becomes a path.
#[must_use]
pub fn robot_file(dir: &Path, robot: &str, name: &str) -> Option<(PathBuf, u64)> {
    let (name, bytes) = robot_files(dir, robot)
        .into_iter()
        .find(|(listed, _)| listed == name)?;
    Some((dir.join(robot_directory(robot)).join(name), bytes))
}

/// A robot's files, oldest first, and their total.
#[derive(Default)]
struct Held {
    files: std::collections::VecDeque<(PathBuf, u64)>,
    bytes: u64,
}

impl Held {
    /// Removes the oldest file; its size if it went (a file that cannot go leaves the list
    /// all the same, so that no turn loops on it).
    fn remove_oldest(&mut self) -> Option<u64> {
        let (path, size) = self.files.pop_front()?;
        self.bytes -= size;
        fs::remove_file(&path).ok().map(|()| size)
    }
}

/// Retention: every robot's oldest files past its share, then, while the fleet is past its
/// own, the oldest file of the robot that holds the most (files when the count is over, bytes
/// when the bytes are); how many went.
fn prune(settings: &StoreSettings) -> u64 {
    let mut robots: BTreeMap<PathBuf, Held> = BTreeMap::new();
    for (path, size) in files(&settings.dir) {
        let robot = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let held = robots.entry(robot).or_default();
        held.files.push_back((path, size));
        held.bytes += size;
    }
    let mut removed = 0;
    for held in robots.values_mut() {
        while held.files.len() > settings.robot_max_files || held.bytes > settings.robot_max_bytes {
            if held.remove_oldest().is_some() {
                removed += 1;
            }
        }
    }
    loop {
        let count: usize = robots.values().map(|held| held.files.len()).sum();
        let bytes: u64 = robots.values().map(|held| held.bytes).sum();
        let most = if count > settings.max_files {
            robots.values_mut().max_by_key(|held| held.files.len())
        } else if bytes > settings.max_bytes {
            robots.values_mut().max_by_key(|held| held.bytes)
        } else {
            break;
        };
        let Some(most) = most.filter(|held| !held.files.is_empty()) else {
            break;
        };
        if most.remove_oldest().is_some() {
            removed += 1;
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, UNIX_EPOCH};

    use super::{StoreSettings, civil_from_days, files, prune, robot_directory, utc_stamp};

    /// `files` files of `bytes` each for every robot, named in time order across robots.
    fn fill(dir: &std::path::Path, robots: &[(&str, usize, usize)]) {
        let mut second = 0;
        for (robot, count, bytes) in robots {
            let robot_dir = dir.join(robot);
            std::fs::create_dir_all(&robot_dir).expect("a robot folder");
            for _ in 0..*count {
                second += 1;
                let name = format!("2026-12-05T10-00-{second:02}.000Z-gap.mcap");
                std::fs::write(robot_dir.join(name), vec![0_u8; *bytes]).expect("a file");
            }
        }
    }

    /// Each robot's file count, by robot folder.
    fn counts(dir: &std::path::Path) -> Vec<(String, usize)> {
        let mut by_robot = std::collections::BTreeMap::new();
        for (path, _) in files(dir) {
            let robot = path.parent().and_then(|p| p.file_name()).expect("a folder");
            *by_robot
                .entry(robot.to_string_lossy().into_owned())
                .or_insert(0) += 1;
        }
        by_robot.into_iter().collect()
    }

    fn settings(dir: &std::path::Path, fleet: (usize, u64), robot: (usize, u64)) -> StoreSettings {
        StoreSettings {
            dir: dir.to_path_buf(),
            max_files: fleet.0,
            max_bytes: fleet.1,
            robot_max_files: robot.0,
            robot_max_bytes: robot.1,
        }
    }

    #[test]
    fn a_robot_keeps_its_own_share_and_no_more() {
        let dir = tempfile::tempdir().expect("a folder");
        // The noisy robot's files are the newest: a fleet-wide "oldest first" would take
        // the quiet robots' instead.
        fill(
            dir.path(),
            &[("quiet-1", 3, 10), ("quiet-2", 2, 10), ("noisy", 40, 10)],
        );
        assert_eq!(
            prune(&settings(dir.path(), (100, 1 << 20), (10, 1 << 20))),
            30
        );
        assert_eq!(
            counts(dir.path()),
            [
                ("noisy".to_owned(), 10),
                ("quiet-1".to_owned(), 3),
                ("quiet-2".to_owned(), 2)
            ]
        );
        // By bytes alike: 35 bytes hold three files of 10.
        assert_eq!(prune(&settings(dir.path(), (100, 1 << 20), (10, 35))), 7);
        assert_eq!(counts(dir.path())[0], ("noisy".to_owned(), 3));
        // The newest are the ones kept.
        let kept: Vec<String> = files(dir.path())
            .into_iter()
            .filter(|(path, _)| path.to_string_lossy().contains("noisy"))
            .map(|(path, _)| {
                path.file_name()
                    .expect("a name")
                    .to_string_lossy()
                    .into_owned()
            })
            .collect();
        assert_eq!(kept.len(), 3);
        assert!(
            kept.iter()
                .all(|name| name.as_str() >= "2026-12-05T10-00-43"),
            "{kept:?}"
        );
    }

    #[test]
    fn past_the_fleet_cap_the_robot_holding_the_most_gives_way() {
        let dir = tempfile::tempdir().expect("a folder");
        fill(dir.path(), &[("a", 5, 10), ("b", 8, 10), ("c", 2, 10)]);
        // 15 files, 10 allowed: each turn the robot with the most gives its oldest (b four, a one).
        assert_eq!(
            prune(&settings(dir.path(), (10, 1 << 20), (100, 1 << 20))),
            5
        );
        assert_eq!(
            counts(dir.path()),
            [
                ("a".to_owned(), 4),
                ("b".to_owned(), 4),
                ("c".to_owned(), 2)
            ]
        );
        // Over the fleet's bytes: the biggest holder by bytes gives way.
        fill(dir.path(), &[("d", 1, 500)]);
        assert_eq!(prune(&settings(dir.path(), (100, 400), (100, 1 << 20))), 1);
        assert!(counts(dir.path()).iter().all(|(robot, _)| robot != "d"));
    }

    #[test]
    fn robot_ids_become_one_safe_directory_each() {
        assert_eq!(robot_directory("r1"), "r1");
        assert_eq!(
            robot_directory("site/cell-2/ur_10"),
            "site%2Fcell-2%2Fur_10"
        );
        assert_eq!(robot_directory(".."), "%2E%2E");
        assert_eq!(robot_directory("a\\b:c"), "a%5Cb%3Ac");
        assert_ne!(robot_directory("a/b"), robot_directory("a_b"));
        let long = "x/".repeat(200);
        let name = robot_directory(&long);
        assert!(name.len() <= 120, "{}", name.len());
        assert_ne!(name, robot_directory(&"x/".repeat(201)));
        assert!(!name.contains('/'));
    }

    #[test]
    fn wall_times_are_named_in_utc_to_the_millisecond() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(19_723), (2024, 1, 1));
        assert_eq!(civil_from_days(11_016), (2000, 2, 29));
        let at = UNIX_EPOCH + Duration::from_millis(1_764_840_324_123);
        assert_eq!(utc_stamp(at), "20251204T092524.123Z");
    }
}
