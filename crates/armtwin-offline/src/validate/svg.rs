//! Small, dependency-free SVG charts for the validation report: line charts of series over time
//! and a histogram. Pure string building; the caller writes the files.
//!
//! Every chart's plot area is a `<g class="plot">` carrying the data range it maps
//! (`data-x-min`, `data-x-max`, `data-y-min`, `data-y-max`) and its pixel box, and every series is a
//! `<polyline class="series" data-name="…">` (histogram bars are `<rect class="bar">` with their
//! bin edges and count), so a reader — or a test — can recover the plotted values.
//! Long series are thinned per pixel column to the first, smallest, largest and last point, which
//! keeps every extreme and the shape while bounding the file size.

use std::fmt::Write as _;

const WIDTH: f64 = 960.0;
const HEIGHT: f64 = 420.0;
const LEFT: f64 = 84.0;
const RIGHT: f64 = 24.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 56.0;
/// Colour-blind-safe palette (Okabe–Ito).
const COLOURS: [&str; 6] = [
    "#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9",
];

/// One named series of `(x, y)` points.
#[derive(Debug, Clone, PartialEq)]
pub struct Series<'a> {
    /// Legend name.
    pub name: &'a str,
    /// Points in x order; non-finite points are skipped.
    pub points: Vec<(f64, f64)>,
    /// Drawn dashed (to tell a reference from the measured line).
    pub dashed: bool,
}

/// Axis range with a margin, never empty.
fn range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if lo > hi {
        return None;
    }
    if hi - lo <= f64::EPSILON * hi.abs().max(1.0) {
        let pad = (hi.abs() * 0.01).max(1e-9);
        return Some((lo - pad, hi + pad));
    }
    Some((lo, hi))
}

/// Tick positions (a 1-2-5 step) covering `[lo, hi]`, and the step.
fn ticks(lo: f64, hi: f64, target: usize) -> (Vec<f64>, f64) {
    let raw = (hi - lo) / target as f64;
    let magnitude = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * magnitude)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * magnitude);
    let first = (lo / step).ceil();
    let count = ((hi / step).floor() - first) as i64;
    let ticks = (0..=count.max(0))
        .map(|k| (first + k as f64) * step)
        .collect();
    (ticks, step)
}

/// A tick label with as many decimals as the step needs.
fn label(value: f64, step: f64) -> String {
    #[allow(clippy::cast_sign_loss, reason = "clamped to ≥ 0 first")]
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    if value == 0.0 {
        "0".to_owned()
    } else if decimals > 5 || value.abs() >= 1e6 {
        format!("{value:.1e}")
    } else {
        format!("{value:.decimals$}")
    }
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Pixel mapping of a data range into the plot box.
#[derive(Clone, Copy)]
struct Frame {
    x: (f64, f64),
    y: (f64, f64),
}

impl Frame {
    fn px(self, x: f64) -> f64 {
        LEFT + (x - self.x.0) / (self.x.1 - self.x.0) * (WIDTH - LEFT - RIGHT)
    }

    fn py(self, y: f64) -> f64 {
        HEIGHT - BOTTOM - (y - self.y.0) / (self.y.1 - self.y.0) * (HEIGHT - TOP - BOTTOM)
    }
}

/// The chart's opening, title, axes with ticks and labels, and the plot group's opening tag.
fn open_chart(out: &mut String, title: &str, x_label: &str, y_label: &str, frame: Frame) {
    let (x_ticks, x_step) = ticks(frame.x.0, frame.x.1, 8);
    let (y_ticks, y_step) = ticks(frame.y.0, frame.y.1, 6);
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" viewBox="0 0 {WIDTH} {HEIGHT}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(out, "<title>{}</title>", escape(title));
    let _ = writeln!(
        out,
        r#"<rect width="{WIDTH}" height="{HEIGHT}" fill="white"/><text x="{}" y="22" text-anchor="middle" font-size="15">{}</text>"#,
        WIDTH / 2.0,
        escape(title)
    );
    let (left, right, top, bottom) = (LEFT, WIDTH - RIGHT, TOP, HEIGHT - BOTTOM);
    for &t in &x_ticks {
        let x = frame.px(t);
        let _ = writeln!(
            out,
            r##"<line x1="{x:.2}" y1="{top}" x2="{x:.2}" y2="{bottom}" stroke="#e4e4e4"/><text x="{x:.2}" y="{}" text-anchor="middle">{}</text>"##,
            bottom + 16.0,
            label(t, x_step)
        );
    }
    for &t in &y_ticks {
        let y = frame.py(t);
        let _ = writeln!(
            out,
            r##"<line x1="{left}" y1="{y:.2}" x2="{right}" y2="{y:.2}" stroke="#e4e4e4"/><text x="{}" y="{:.2}" text-anchor="end">{}</text>"##,
            left - 6.0,
            y + 4.0,
            label(t, y_step)
        );
    }
    let _ = writeln!(
        out,
        r##"<rect x="{left}" y="{top}" width="{}" height="{}" fill="none" stroke="#444"/>"##,
        right - left,
        bottom - top
    );
    let _ = writeln!(
        out,
        r#"<text x="{}" y="{}" text-anchor="middle">{}</text><text transform="translate(18 {}) rotate(-90)" text-anchor="middle">{}</text>"#,
        f64::midpoint(left, right),
        HEIGHT - 14.0,
        escape(x_label),
        f64::midpoint(top, bottom),
        escape(y_label)
    );
    let _ = writeln!(
        out,
        r#"<g class="plot" data-x-min="{:e}" data-x-max="{:e}" data-y-min="{:e}" data-y-max="{:e}" data-left="{left}" data-right="{right}" data-top="{top}" data-bottom="{bottom}">"#,
        frame.x.0, frame.x.1, frame.y.0, frame.y.1
    );
}

/// Thins `points` to at most four per pixel column: first, smallest, largest, last.
fn thin(points: &[(f64, f64)], frame: Frame) -> Vec<(f64, f64)> {
    let mut kept: Vec<(f64, f64)> = Vec::new();
    let mut column: Option<i64> = None;
    let mut bucket: Vec<(f64, f64)> = Vec::new();
    let flush = |bucket: &mut Vec<(f64, f64)>, kept: &mut Vec<(f64, f64)>| {
        if bucket.is_empty() {
            return;
        }
        let low = bucket
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.1.total_cmp(&b.1.1))
            .map_or(0, |(i, _)| i);
        let high = bucket
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.1.total_cmp(&b.1.1))
            .map_or(0, |(i, _)| i);
        let mut picks = vec![0, low, high, bucket.len() - 1];
        picks.sort_unstable();
        picks.dedup();
        kept.extend(picks.into_iter().map(|i| bucket[i]));
        bucket.clear();
    };
    for &(x, y) in points
        .iter()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
    {
        let c = frame.px(x).floor() as i64;
        if column != Some(c) {
            flush(&mut bucket, &mut kept);
            column = Some(c);
        }
        bucket.push((x, y));
    }
    flush(&mut bucket, &mut kept);
    kept
}

/// A line chart of `series` against a shared x axis.
#[must_use]
pub fn line_chart(title: &str, x_label: &str, y_label: &str, series: &[Series<'_>]) -> String {
    let all = || series.iter().flat_map(|s| s.points.iter());
    let x = range(all().map(|p| p.0)).unwrap_or((0.0, 1.0));
    let y = range(all().filter(|p| p.0.is_finite()).map(|p| p.1)).unwrap_or((0.0, 1.0));
    let pad = (y.1 - y.0) * 0.05;
    let frame = Frame {
        x,
        y: (y.0 - pad, y.1 + pad),
    };
    let mut out = String::new();
    open_chart(&mut out, title, x_label, y_label, frame);
    for (index, s) in series.iter().enumerate() {
        let colour = COLOURS[index % COLOURS.len()];
        let dash = if s.dashed {
            r#" stroke-dasharray="6 3""#
        } else {
            ""
        };
        let _ = write!(
            out,
            r#"<polyline class="series" data-name="{}" fill="none" stroke="{colour}" stroke-width="1.3"{dash} points=""#,
            escape(s.name)
        );
        for (px, py) in thin(&s.points, frame) {
            let _ = write!(out, "{:.2},{:.2} ", frame.px(px), frame.py(py));
        }
        out.push_str("\"/>\n");
    }
    out.push_str("</g>\n");
    let legend_x = WIDTH - RIGHT - 158.0;
    let _ = writeln!(
        out,
        r##"<rect x="{legend_x}" y="{}" width="150" height="{}" fill="white" fill-opacity="0.85" stroke="#bbb"/>"##,
        TOP + 4.0,
        16.0 * series.len() as f64 + 8.0
    );
    for (index, s) in series.iter().enumerate() {
        let colour = COLOURS[index % COLOURS.len()];
        let y = TOP + 16.0 + 16.0 * index as f64;
        let x = legend_x + 8.0;
        let _ = writeln!(
            out,
            r#"<line x1="{x}" y1="{y}" x2="{}" y2="{y}" stroke="{colour}" stroke-width="2"/><text x="{}" y="{}">{}</text>"#,
            x + 20.0,
            x + 26.0,
            y + 4.0,
            escape(s.name)
        );
    }
    out.push_str("</svg>\n");
    out
}

/// A histogram of `values` in `bins` equal bins.
#[must_use]
pub fn histogram(title: &str, x_label: &str, values: &[f64], bins: usize) -> String {
    let bins = bins.max(1);
    let (lo, hi) = range(values.iter().copied()).unwrap_or((0.0, 1.0));
    let width = (hi - lo) / bins as f64;
    let mut counts = vec![0u64; bins];
    for &v in values.iter().filter(|v| v.is_finite()) {
        #[allow(clippy::cast_sign_loss, reason = "v ≥ lo, so the quotient is ≥ 0")]
        let bin = (((v - lo) / width).floor() as usize).min(bins - 1);
        counts[bin] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
    let frame = Frame {
        x: (lo, hi),
        y: (0.0, top * 1.05),
    };
    let mut out = String::new();
    open_chart(&mut out, title, x_label, "rows", frame);
    for (bin, &count) in counts.iter().enumerate() {
        let from = lo + bin as f64 * width;
        let to = from + width;
        let (x0, x1) = (frame.px(from), frame.px(to));
        let (y0, y1) = (frame.py(count as f64), frame.py(0.0));
        let _ = writeln!(
            out,
            r##"<rect class="bar" data-from="{from:e}" data-to="{to:e}" data-count="{count}" x="{x0:.2}" y="{y0:.2}" width="{:.2}" height="{:.2}" fill="#0072B2" stroke="white" stroke-width="0.5"/>"##,
            (x1 - x0).max(0.0),
            (y1 - y0).max(0.0)
        );
    }
    out.push_str("</g>\n</svg>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_follow_one_two_five() {
        let (t, step) = ticks(0.0, 1.0, 5);
        assert!((step - 0.2).abs() < 1e-12, "{step}");
        assert_eq!(t.len(), 6);
        assert_eq!(label(0.4, step), "0.4");
        assert_eq!(label(2.5e-6, 1e-6), "2.5e-6");
    }

    #[test]
    fn thinning_keeps_every_extreme() {
        let points: Vec<(f64, f64)> = (0..100_000)
            .map(|k| {
                (
                    f64::from(k),
                    (f64::from(k) * 0.37).sin() + f64::from(k == 77_777) * 5.0,
                )
            })
            .collect();
        let frame = Frame {
            x: (0.0, 99_999.0),
            y: (-1.0, 6.0),
        };
        let kept = thin(&points, frame);
        assert!(kept.len() <= 4 * 960, "{}", kept.len());
        let max = kept.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
        assert!((max - points[77_777].1).abs() < 1e-15);
        assert_eq!(kept.first(), points.first());
        assert_eq!(kept.last(), points.last());
    }

    #[test]
    fn histogram_counts_every_value_once() {
        let values: Vec<f64> = (0..1000).map(|k| f64::from(k % 10)).collect();
        let svg = histogram("h", "v", &values, 10);
        let total: u64 = svg
            .split("data-count=\"")
            .skip(1)
            .map(|s| s.split('"').next().unwrap().parse::<u64>().unwrap())
            .sum();
        assert_eq!(total, 1000);
    }
}
