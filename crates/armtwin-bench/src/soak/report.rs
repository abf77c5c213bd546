//! `soak.json`'s types, the summary of a soak (the RSS slope, the p99's stability, loss, CPU),
//! its targets, the table printed and the SVG curves.
//!
//! Pure: computes and formats from the rows; the caller writes the files.

use std::fmt::Write as _;

use armtwin_offline::validate::svg::{Series, line_chart};
use serde::Serialize;

use super::Settings;
use super::watch::WatchSummary;
use crate::load::Soak;
use crate::run::Host;

/// The RSS slope after the warm-up that counts as flat (MiB per hour).
pub const RSS_SLOPE_TARGET_MIB_PER_H: f64 = 1.0;
/// The p99 counts as stable when, over the intervals after the warm-up, both the median and the
/// highest p99 of the last third are at most this many times the first third's: the median
/// follows the usual interval, the highest the outliers (intervals with a churn).
pub const P99_DRIFT_TARGET: f64 = 1.5;

/// One interval: the load's view and the service's process beside it.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// 0, 1, …
    pub index: usize,
    /// Seconds from the soak's start to the interval's end.
    pub end_s: f64,
    /// Resident memory of armtwin when the interval was reported (MiB).
    pub rss_mib: f64,
    /// armtwin's CPU over the interval (% of one core).
    pub cpu_percent: f64,
    /// The load generator's CPU over the interval (% of one core).
    pub load_cpu_percent: f64,
    /// Samples sent in the interval.
    pub sent: u64,
    /// Their poses back within the load's grace.
    pub received: u64,
    /// `sent − received`.
    pub unanswered: u64,
    /// Latency sample sent → pose received (µs; NaN, written null, without poses).
    pub p50_us: f64,
    /// 99th percentile (µs).
    pub p99_us: f64,
    /// Largest (µs).
    pub max_us: f64,
    /// `armtwin_robots_tracked` as last scraped.
    pub robots_tracked: Option<f64>,
    /// Robots that had left (and as many new ones joined) by the interval's end.
    pub churned: u64,
}

/// The figures of the whole soak.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// RSS before the first sample (MiB).
    pub rss_before_mib: f64,
    /// RSS at the first interval (MiB).
    pub rss_first_mib: f64,
    /// RSS at the end of the warm-up (the first interval after it, MiB).
    pub rss_after_warm_up_mib: Option<f64>,
    /// RSS at the last interval (MiB).
    pub rss_last_mib: f64,
    /// The largest RSS of any interval (MiB).
    pub rss_max_mib: f64,
    /// Least-squares slope of RSS over the intervals after the warm-up (MiB per hour).
    pub rss_slope_mib_per_h: Option<f64>,
    /// Intervals after the warm-up.
    pub intervals_after_warm_up: usize,
    /// p50 over the intervals after the warm-up: lowest and highest (µs).
    pub p50_range_us: (f64, f64),
    /// p99 over the intervals after the warm-up: lowest, median and highest (µs).
    pub p99_range_us: (f64, f64, f64),
    /// Median p99 of the first and of the last third of the intervals after the warm-up (µs).
    pub p99_thirds_us: (f64, f64),
    /// The last third's median p99 over the first third's.
    pub p99_drift: f64,
    /// Highest p99 of the first and of the last third of the intervals after the warm-up (µs).
    pub p99_thirds_highest_us: (f64, f64),
    /// The last third's highest p99 over the first third's.
    pub p99_highest_drift: f64,
    /// The largest latency of any interval (µs).
    pub max_us: f64,
    /// Samples sent.
    pub sent: u64,
    /// Poses and deviations that never came back.
    pub lost: u64,
    /// Poses later than their interval's report.
    pub late: u64,
    /// CPU seconds armtwin used over the soak, and that as % of one core.
    pub cpu_s: f64,
    /// armtwin's average CPU (% of one core).
    pub cpu_percent: f64,
    /// The load generator's average CPU (% of one core).
    pub load_cpu_percent: f64,
    /// Robots tracked after the warm-up: fewest and most scraped.
    pub robots_tracked_range: Option<(f64, f64)>,
    /// Robots that left (as many new ones joined).
    pub churned: u64,
}

/// A target, met or not.
#[derive(Debug, Clone, Serialize)]
pub struct Target {
    /// What is aimed at.
    pub target: String,
    /// The figure.
    pub current: String,
    /// Whether it is met.
    pub met: bool,
}

/// `soak.json`.
#[derive(Debug, Clone, Serialize)]
pub struct SoakReport {
    /// Unix time (s) of the start.
    pub started_unix_s: u64,
    /// The machine.
    pub host: Host,
    /// The settings, defaults filled in.
    pub settings: Settings,
    /// Whether `[service] forget_after_s` was set (robots retired).
    pub retirement: bool,
    /// The summary.
    pub summary: Summary,
    /// The targets.
    pub targets: Vec<Target>,
    /// Every interval.
    pub rows: Vec<Row>,
    /// Prometheus (or this process) and the dashboard client.
    pub watchers: WatchSummary,
    /// The load generator's own account.
    pub load: Soak,
    /// Wall-clock seconds of the whole command.
    pub wall_s: f64,
}

/// Least-squares slope of `points` (per unit of x); `None` under two distinct x.
#[must_use]
pub fn slope(points: &[(f64, f64)]) -> Option<f64> {
    let n = points.len() as f64;
    if points.len() < 2 {
        return None;
    }
    let mean_x = points.iter().map(|p| p.0).sum::<f64>() / n;
    let mean_y = points.iter().map(|p| p.1).sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (x, y) in points {
        sxy += (x - mean_x) * (y - mean_y);
        sxx += (x - mean_x) * (x - mean_x);
    }
    (sxx > 0.0).then(|| sxy / sxx)
}

fn median(values: &[f64]) -> f64 {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted.sort_by(f64::total_cmp);
    let middle = sorted.len() / 2;
    if sorted.len().is_multiple_of(2) {
        f64::midpoint(sorted[middle - 1], sorted[middle])
    } else {
        sorted[middle]
    }
}

fn extremes(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values
        .filter(|v| v.is_finite())
        .fold((f64::NAN, f64::NAN), |(lo, hi), v| (v.min(lo), v.max(hi)))
}

/// The summary of `rows`, the intervals ending after `warm_up_s` counting for the slope and the
/// p99's stability (all of them if none does).
#[must_use]
pub fn summarize(
    rows: &[Row],
    warm_up_s: f64,
    rss_before_mib: f64,
    load: &Soak,
    cpu_s: f64,
    wall_s: f64,
) -> Summary {
    let after: Vec<&Row> = rows.iter().filter(|r| r.end_s > warm_up_s).collect();
    let after = if after.is_empty() {
        rows.iter().collect()
    } else {
        after
    };
    let rss_points: Vec<(f64, f64)> = after
        .iter()
        .map(|r| (r.end_s / 3600.0, r.rss_mib))
        .collect();
    let p99: Vec<f64> = after.iter().map(|r| r.p99_us).collect();
    let third = (p99.len() / 3).max(1);
    let (first, last) = (
        &p99[..third.min(p99.len())],
        &p99[p99.len().saturating_sub(third)..],
    );
    let (first_third, last_third) = (median(first), median(last));
    let highest = |values: &[f64]| extremes(values.iter().copied()).1;
    let (first_highest, last_highest) = (highest(first), highest(last));
    let (p99_lo, p99_hi) = extremes(p99.iter().copied());
    let tracked: Vec<f64> = after.iter().filter_map(|r| r.robots_tracked).collect();
    let load_cpu = rows.iter().map(|r| r.load_cpu_percent).sum::<f64>() / rows.len().max(1) as f64;
    Summary {
        rss_before_mib,
        rss_first_mib: rows.first().map_or(f64::NAN, |r| r.rss_mib),
        rss_after_warm_up_mib: rows.iter().find(|r| r.end_s > warm_up_s).map(|r| r.rss_mib),
        rss_last_mib: rows.last().map_or(f64::NAN, |r| r.rss_mib),
        rss_max_mib: extremes(rows.iter().map(|r| r.rss_mib)).1,
        rss_slope_mib_per_h: slope(&rss_points),
        intervals_after_warm_up: after.len(),
        p50_range_us: extremes(after.iter().map(|r| r.p50_us)),
        p99_range_us: (p99_lo, median(&p99), p99_hi),
        p99_thirds_us: (first_third, last_third),
        p99_drift: last_third / first_third,
        p99_thirds_highest_us: (first_highest, last_highest),
        p99_highest_drift: last_highest / first_highest,
        max_us: extremes(rows.iter().map(|r| r.max_us)).1,
        sent: load.sent,
        lost: load.lost,
        late: load.late,
        cpu_s,
        cpu_percent: 100.0 * cpu_s / wall_s.max(f64::MIN_POSITIVE),
        load_cpu_percent: load_cpu,
        robots_tracked_range: (!tracked.is_empty()).then(|| extremes(tracked.into_iter())),
        churned: load.churned,
    }
}

/// The soak's targets: nothing lost, RSS flat after the warm-up, p99 stable.
#[must_use]
pub fn targets(summary: &Summary) -> Vec<Target> {
    let slope = summary.rss_slope_mib_per_h;
    vec![
        Target {
            target: "zero loss".to_owned(),
            current: format!(
                "{} lost of {} samples ({} late)",
                summary.lost, summary.sent, summary.late
            ),
            met: summary.lost == 0,
        },
        Target {
            target: format!("RSS slope after warm-up ≤ {RSS_SLOPE_TARGET_MIB_PER_H} MiB/h"),
            current: slope.map_or_else(|| "—".to_owned(), |s| format!("{s:.2} MiB/h")),
            met: slope.is_some_and(|s| s <= RSS_SLOPE_TARGET_MIB_PER_H),
        },
        Target {
            target: format!(
                "p99 stable (the last third's median and highest ≤ {P99_DRIFT_TARGET} × the first third's)"
            ),
            current: format!(
                "median {:.0} → {:.0} µs (× {:.2}), highest {:.0} → {:.0} µs (× {:.2})",
                summary.p99_thirds_us.0,
                summary.p99_thirds_us.1,
                summary.p99_drift,
                summary.p99_thirds_highest_us.0,
                summary.p99_thirds_highest_us.1,
                summary.p99_highest_drift
            ),
            met: summary.p99_drift <= P99_DRIFT_TARGET
                && summary.p99_highest_drift <= P99_DRIFT_TARGET,
        },
    ]
}

/// One interval as printed while the soak runs.
#[must_use]
pub fn row_line(row: &Row) -> String {
    format!(
        "{:>7.0} s  RSS {:>7.1} MiB  CPU {:>5.1} %  load {:>5.1} %  sent {:>7}  back {:>7}  unanswered {:>4}  p50 {:>6.0} µs  p99 {:>7.0} µs  max {:>8.0} µs  tracked {:>5}  churned {}",
        row.end_s,
        row.rss_mib,
        row.cpu_percent,
        row.load_cpu_percent,
        row.sent,
        row.received,
        row.unanswered,
        row.p50_us,
        row.p99_us,
        row.max_us,
        row.robots_tracked
            .map_or_else(|| "?".to_owned(), |t| format!("{t:.0}")),
        row.churned
    )
}

/// The summary and targets as a Markdown table.
#[must_use]
pub fn table(report: &SoakReport) -> String {
    let s = &report.summary;
    let settings = &report.settings;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "soak: {} robots × {} Hz, {} s, {} % replaced every {} s, retirement {}, metrics scraped by {}",
        settings.robots,
        settings.hz,
        settings.duration_s,
        settings.churn * 100.0,
        settings.churn_period_s,
        settings
            .forget_after_s
            .map_or_else(|| "off".to_owned(), |f| format!("after {f} s")),
        report.watchers.scraper,
    );
    let _ = writeln!(out, "\n| figure | value |\n| --- | ---: |");
    let mut line = |name: &str, value: String| {
        let _ = writeln!(out, "| {name} | {value} |");
    };
    line(
        "RSS before / first interval / after warm-up / last / max (MiB)",
        format!(
            "{:.1} / {:.1} / {} / {:.1} / {:.1}",
            s.rss_before_mib,
            s.rss_first_mib,
            s.rss_after_warm_up_mib
                .map_or_else(|| "—".to_owned(), |r| format!("{r:.1}")),
            s.rss_last_mib,
            s.rss_max_mib
        ),
    );
    line(
        "RSS slope after warm-up (MiB/h)",
        s.rss_slope_mib_per_h
            .map_or_else(|| "—".to_owned(), |v| format!("{v:.2}")),
    );
    line(
        "p50 per interval, lowest–highest (µs)",
        format!("{:.0}–{:.0}", s.p50_range_us.0, s.p50_range_us.1),
    );
    line(
        "p99 per interval, lowest / median / highest (µs)",
        format!(
            "{:.0} / {:.0} / {:.0}",
            s.p99_range_us.0, s.p99_range_us.1, s.p99_range_us.2
        ),
    );
    line("largest latency (µs)", format!("{:.0}", s.max_us));
    line(
        "samples sent / lost / late",
        format!("{} / {} / {}", s.sent, s.lost, s.late),
    );
    line(
        "CPU armtwin / load (% of one core)",
        format!("{:.1} / {:.1}", s.cpu_percent, s.load_cpu_percent),
    );
    line(
        "robots tracked after warm-up (fewest–most)",
        s.robots_tracked_range
            .map_or_else(|| "—".to_owned(), |(lo, hi)| format!("{lo:.0}–{hi:.0}")),
    );
    line(
        "robots churned (left, as many new joined)",
        s.churned.to_string(),
    );
    let w = &report.watchers;
    line(
        "scrapes ok / failed; dashboard fetches ok / failed",
        format!(
            "{} / {}; {} / {}",
            w.scrapes, w.scrape_failures, w.dashboard_fetches, w.dashboard_failures
        ),
    );
    let _ = writeln!(out, "\n| target | current | met |\n| --- | --- | --- |");
    for target in &report.targets {
        let _ = writeln!(
            out,
            "| {} | {} | {} |",
            target.target,
            target.current,
            if target.met { "yes" } else { "no" }
        );
    }
    out
}

/// RSS, latency and robots tracked over the soak: three charts of `validate`'s kind, stacked in
/// one SVG.
#[must_use]
pub fn curves(report: &SoakReport) -> String {
    let minutes = |row: &Row| row.end_s / 60.0;
    let points = |value: fn(&Row) -> f64| -> Vec<(f64, f64)> {
        report.rows.iter().map(|r| (minutes(r), value(r))).collect()
    };
    let charts = [
        line_chart(
            "armtwin resident memory",
            "minutes",
            "RSS (MiB)",
            &[Series {
                name: "RSS",
                points: points(|r| r.rss_mib),
                dashed: false,
            }],
        ),
        line_chart(
            "latency per interval, joint sample sent → twin pose received",
            "minutes",
            "latency (ms)",
            &[
                Series {
                    name: "p99",
                    points: points(|r| r.p99_us / 1e3),
                    dashed: false,
                },
                Series {
                    name: "p50",
                    points: points(|r| r.p50_us / 1e3),
                    dashed: true,
                },
            ],
        ),
        line_chart(
            "robots tracked (armtwin_robots_tracked)",
            "minutes",
            "robots",
            &[Series {
                name: "tracked",
                points: points(|r| r.robots_tracked.unwrap_or(f64::NAN)),
                dashed: false,
            }],
        ),
    ];
    let (width, height) = (960, 420);
    let mut out = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{}" viewBox="0 0 {width} {}">"#,
        height * charts.len(),
        height * charts.len()
    );
    out.push('\n');
    for (index, chart) in charts.iter().enumerate() {
        let _ = writeln!(
            out,
            r#"<g transform="translate(0 {})">{chart}</g>"#,
            index * height
        );
    }
    out.push_str("</svg>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_slope_of_a_line_is_its_gradient() {
        let points: Vec<(f64, f64)> = (0..10)
            .map(|i| (f64::from(i), 3.0 + 0.5 * f64::from(i)))
            .collect();
        assert!((slope(&points).expect("slope") - 0.5).abs() < 1e-12);
        assert!(slope(&points[..1]).is_none());
        assert!(slope(&[(1.0, 1.0), (1.0, 2.0)]).is_none());
    }

    #[test]
    fn the_median_ignores_missing_values() {
        assert!((median(&[3.0, f64::NAN, 1.0, 2.0]) - 2.0).abs() < 1e-12);
        assert!((median(&[4.0, 1.0, 2.0, 3.0]) - 2.5).abs() < 1e-12);
        assert!(median(&[]).is_nan());
    }
}
