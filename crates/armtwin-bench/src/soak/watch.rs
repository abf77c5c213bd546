//! What watches the service while the soak runs, as in production: Prometheus scraping
//! `/metrics` (a real one when a binary is given, else this process scraping at the same pace),
//! and a dashboard client fetching the fleet page and its API.
//!
//! Owns those watchers' threads and process; reads `armtwin_robots_tracked` for the report and
//! judges nothing.

use std::fmt::Write as _;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use serde::Serialize;

use crate::http;
use crate::procfs;
use crate::run::system::{SystemUnderTest, free_port, wait_listening};

/// How long one HTTP request may take.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(10);
/// The gauge of robots the service tracks.
const ROBOTS_TRACKED: &str = "armtwin_robots_tracked";
/// Every how many fleet API fetches the dashboard client also loads the fleet page.
const PAGE_EVERY: u64 = 10;

/// Counters the watcher threads share.
#[derive(Debug, Default)]
struct Counters {
    scrapes: AtomicU64,
    scrape_failures: AtomicU64,
    /// The last scraped `armtwin_robots_tracked` (`f64` bits; `u64::MAX`: none yet).
    robots_tracked_bits: AtomicU64,
    dashboard_fetches: AtomicU64,
    dashboard_failures: AtomicU64,
    dashboard_bytes: AtomicU64,
    dashboard_slowest_us: AtomicU64,
}

/// What scrapes `/metrics`.
enum Scraper {
    /// A Prometheus process, its query API on `address`.
    Prometheus {
        process: SystemUnderTest,
        address: SocketAddr,
    },
    /// A thread of this process.
    Own,
}

/// What the watchers did, for the report.
#[derive(Debug, Clone, Serialize)]
pub struct WatchSummary {
    /// `prometheus` (a real Prometheus scraped) or `own` (this process scraped).
    pub scraper: &'static str,
    /// The Prometheus binary, if one ran.
    pub prometheus: Option<PathBuf>,
    /// Seconds between scrapes.
    pub scrape_interval_s: f64,
    /// Scrapes of `/metrics` that succeeded.
    pub scrapes: u64,
    /// Scrapes that failed.
    pub scrape_failures: u64,
    /// CPU seconds Prometheus used.
    pub prometheus_cpu_s: Option<f64>,
    /// Seconds between two fleet API fetches of the dashboard client.
    pub dashboard_period_s: f64,
    /// Fleet API and fleet page fetches answered 200.
    pub dashboard_fetches: u64,
    /// Fetches that failed or were not 200.
    pub dashboard_failures: u64,
    /// Bytes the dashboard client received.
    pub dashboard_bytes: u64,
    /// The slowest fetch (ms).
    pub dashboard_slowest_ms: f64,
}

/// The running watchers.
pub(super) struct Watchers {
    scraper: Scraper,
    prometheus_binary: Option<PathBuf>,
    scrape_interval: Duration,
    dashboard_period: Duration,
    started: Instant,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
    threads: Vec<JoinHandle<()>>,
}

impl Watchers {
    /// Starts the scraper (Prometheus when `prometheus` is given) and the dashboard client
    /// against the service's HTTP side on `service`.
    pub(super) fn start(
        service: SocketAddr,
        prometheus: Option<&Path>,
        scrape_interval: Duration,
        dashboard_period: Duration,
        work_dir: &Path,
    ) -> Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let counters = Arc::new(Counters {
            robots_tracked_bits: AtomicU64::new(u64::MAX),
            ..Counters::default()
        });
        let mut threads = Vec::new();
        let scraper = if let Some(binary) = prometheus {
            start_prometheus(binary, service, scrape_interval, work_dir)?
        } else {
            let (stop, counters) = (stop.clone(), counters.clone());
            threads.push(thread::spawn(move || {
                scrape_loop(service, scrape_interval, &stop, &counters);
            }));
            Scraper::Own
        };
        {
            let (stop, counters) = (stop.clone(), counters.clone());
            threads.push(thread::spawn(move || {
                dashboard_loop(service, dashboard_period, &stop, &counters);
            }));
        }
        Ok(Self {
            scraper,
            prometheus_binary: prometheus.map(Path::to_path_buf),
            scrape_interval,
            dashboard_period,
            started: Instant::now(),
            stop,
            counters,
            threads,
        })
    }

    /// `armtwin_robots_tracked` as last scraped: Prometheus' latest sample, or this process's.
    pub(super) fn robots_tracked(&self) -> Option<f64> {
        match &self.scraper {
            Scraper::Prometheus { address, .. } => prometheus_value(*address, ROBOTS_TRACKED),
            Scraper::Own => {
                let bits = self.counters.robots_tracked_bits.load(Ordering::Relaxed);
                (bits != u64::MAX).then(|| f64::from_bits(bits))
            }
        }
    }

    /// Stops every watcher and sums up what they did.
    pub(super) fn stop(self) -> WatchSummary {
        self.stop.store(true, Ordering::Relaxed);
        for thread in self.threads {
            let _ = thread.join();
        }
        let c = &self.counters;
        let (scraper, scrapes, scrape_failures, prometheus_cpu_s) = match self.scraper {
            Scraper::Prometheus { process, address } => {
                // Prometheus' own record of its scrapes over the whole soak.
                let range = format!("[{}s]", self.started.elapsed().as_secs() + 60);
                let attempts = prometheus_value(
                    address,
                    &format!("count_over_time(up{{job=\"armtwin\"}}{range})"),
                );
                let succeeded = prometheus_value(
                    address,
                    &format!("sum_over_time(up{{job=\"armtwin\"}}{range})"),
                );
                let cpu_s = procfs::cpu_s(process.pid()).ok();
                process.stop();
                let attempts = attempts.unwrap_or(0.0) as u64;
                let succeeded = succeeded.unwrap_or(0.0) as u64;
                (
                    "prometheus",
                    succeeded,
                    attempts.saturating_sub(succeeded),
                    cpu_s,
                )
            }
            Scraper::Own => (
                "own",
                c.scrapes.load(Ordering::Relaxed),
                c.scrape_failures.load(Ordering::Relaxed),
                None,
            ),
        };
        WatchSummary {
            scraper,
            prometheus: self.prometheus_binary,
            scrape_interval_s: self.scrape_interval.as_secs_f64(),
            scrapes,
            scrape_failures,
            prometheus_cpu_s,
            dashboard_period_s: self.dashboard_period.as_secs_f64(),
            dashboard_fetches: c.dashboard_fetches.load(Ordering::Relaxed),
            dashboard_failures: c.dashboard_failures.load(Ordering::Relaxed),
            dashboard_bytes: c.dashboard_bytes.load(Ordering::Relaxed),
            dashboard_slowest_ms: c.dashboard_slowest_us.load(Ordering::Relaxed) as f64 / 1e3,
        }
    }
}

/// Prometheus scraping `service` every `scrape_interval`, its data in `work_dir`.
fn start_prometheus(
    binary: &Path,
    service: SocketAddr,
    scrape_interval: Duration,
    work_dir: &Path,
) -> Result<Scraper> {
    let port = free_port()?;
    let config = work_dir.join("prometheus.yml");
    let interval = format!("{}ms", scrape_interval.as_millis().max(1));
    std::fs::write(
        &config,
        format!(
            "global:\n  scrape_interval: {interval}\n  evaluation_interval: {interval}\n\
             scrape_configs:\n  - job_name: armtwin\n    static_configs:\n      - targets: ['{service}']\n"
        ),
    )
    .with_context(|| format!("writing {}", config.display()))?;
    let log = std::fs::File::create(work_dir.join("prometheus.log"))?;
    let mut child = Command::new(binary)
        .arg(format!("--config.file={}", config.display()))
        .arg(format!(
            "--storage.tsdb.path={}",
            work_dir.join("prometheus-data").display()
        ))
        .arg(format!("--web.listen-address=127.0.0.1:{port}"))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .with_context(|| format!("starting {}", binary.display()))?;
    wait_listening(port, &mut child)?;
    Ok(Scraper::Prometheus {
        process: SystemUnderTest {
            child,
            endpoint: format!("127.0.0.1:{port}"),
        },
        address: SocketAddr::from(([127, 0, 0, 1], port)),
    })
}

/// The value of an instant query with one result, from Prometheus' API on `address`.
fn prometheus_value(address: SocketAddr, query: &str) -> Option<f64> {
    let path = format!("/api/v1/query?query={}", percent_encoded(query));
    let response = http::get(address, &path, REQUEST_TIMEOUT).ok()?;
    let answer: serde_json::Value = serde_json::from_slice(&response.body).ok()?;
    let result = answer.pointer("/data/result")?.as_array()?;
    match result.as_slice() {
        [one] => one.pointer("/value/1")?.as_str()?.parse().ok(),
        _ => None,
    }
}

/// `text` with every byte but unreserved ones percent-encoded, for a URL's query.
fn percent_encoded(text: &str) -> String {
    let mut out = String::with_capacity(text.len() * 3);
    for byte in text.bytes() {
        if byte.is_ascii_alphanumeric() || b"-_.~".contains(&byte) {
            out.push(char::from(byte));
        } else {
            let _ = write!(out, "%{byte:02X}");
        }
    }
    out
}

/// Sleeps `period` in short steps, returning early (false) once `stop` is set.
fn pause(period: Duration, stop: &AtomicBool) -> bool {
    let until = Instant::now() + period;
    while Instant::now() < until {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        thread::sleep(Duration::from_millis(50).min(period));
    }
    !stop.load(Ordering::Relaxed)
}

/// Scrapes `/metrics` every `period` and keeps `armtwin_robots_tracked`.
fn scrape_loop(service: SocketAddr, period: Duration, stop: &AtomicBool, counters: &Counters) {
    while !stop.load(Ordering::Relaxed) {
        let tracked = http::get(service, "/metrics", REQUEST_TIMEOUT)
            .ok()
            .filter(|response| response.status == 200)
            .and_then(|response| {
                String::from_utf8_lossy(&response.body)
                    .lines()
                    .find_map(|line| line.strip_prefix(ROBOTS_TRACKED)?.strip_prefix(' '))
                    .and_then(|value| value.trim().parse::<f64>().ok())
            });
        if let Some(tracked) = tracked {
            counters.scrapes.fetch_add(1, Ordering::Relaxed);
            counters
                .robots_tracked_bits
                .store(tracked.to_bits(), Ordering::Relaxed);
        } else {
            counters.scrape_failures.fetch_add(1, Ordering::Relaxed);
        }
        if !pause(period, stop) {
            break;
        }
    }
}

/// Fetches the fleet API every `period`, and the fleet page every [`PAGE_EVERY`] of those.
fn dashboard_loop(service: SocketAddr, period: Duration, stop: &AtomicBool, counters: &Counters) {
    let mut fetch = 0_u64;
    while pause(period, stop) {
        let path = if fetch.is_multiple_of(PAGE_EVERY) {
            "/"
        } else {
            "/api/fleet"
        };
        fetch += 1;
        let started = Instant::now();
        match http::get(service, path, REQUEST_TIMEOUT) {
            Ok(response) if response.status == 200 => {
                counters.dashboard_fetches.fetch_add(1, Ordering::Relaxed);
                counters
                    .dashboard_bytes
                    .fetch_add(response.body.len() as u64, Ordering::Relaxed);
                counters
                    .dashboard_slowest_us
                    .fetch_max(started.elapsed().as_micros() as u64, Ordering::Relaxed);
            }
            _ => {
                counters.dashboard_failures.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queries_are_percent_encoded() {
        assert_eq!(
            percent_encoded("sum_over_time(up{job=\"a\"}[60s])"),
            "sum_over_time%28up%7Bjob%3D%22a%22%7D%5B60s%5D%29"
        );
    }
}
