//! The trials: the echo and `armtwin serve` started on free loopback ports and compared under the
//! same load, row by row, and first contact (robots new to a fresh system at full rate).
//!
//! Owns which processes run with which flags for each row; must not measure (the load generator
//! does) or format the report.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{Context, Result, bail};

use super::Settings;
use super::report::{Comparison, FirstContact, LatencySummary, Paced, median};
use super::system::{SystemUnderTest, free_port, wait_listening};
use crate::fleet::service_config_encoded;
use crate::load::{Latency, LoadReport, Target, Trial, WireEncoding};
use crate::net;

/// Seconds of the paced comparison's unmeasured first round.
const PACED_WARM_UP_S: f64 = 2.0;

fn target_name(target: Target) -> &'static str {
    match target {
        Target::Echo => "echo",
        Target::Armtwin => "armtwin",
    }
}

/// `armtwin-bench load` against `sut`, its stamps counted from `clock_origin_s`, each robot's
/// gateway `seq` kept in `seq_file`; the caller adds what the load runs.
pub(crate) fn load_command(
    bench: &Path,
    sut: &SystemUnderTest,
    target: Target,
    encoding: WireEncoding,
    clock_origin_s: f64,
    seq_file: &Path,
) -> Command {
    let mut command = Command::new(bench);
    command
        .args(["load", "-e", &sut.endpoint, "--target", target_name(target)])
        .args(["--sut-pid", &sut.pid().to_string()])
        .args(["--encoding", encoding.as_str()])
        .args(["--clock-origin", &clock_origin_s.to_string()])
        .arg("--seq-file")
        .arg(seq_file);
    command
}

/// What every trial needs: the settings, the shared clock, the binaries and a scratch folder.
pub(super) struct Orchestrator {
    pub(super) settings: Settings,
    /// Unix time (s) every load process's stamps count from.
    pub(super) clock_origin_s: f64,
    pub(super) bench: PathBuf,
    pub(super) armtwin: PathBuf,
    /// TOML appended to every armtwin configuration (`--armtwin-config-extra`).
    pub(super) config_extra: String,
    pub(super) work_dir: PathBuf,
}

/// `text` with `extra` appended as tables of its own: after a newline, since `text` may end
/// inside a robot's table.
pub(super) fn with_config_extra(text: &str, extra: &str) -> String {
    if extra.is_empty() {
        return text.to_owned();
    }
    format!("{text}\n{extra}\n")
}

impl Orchestrator {
    /// The runs of `settings`, from `bench` and `armtwin`, in `work_dir`; reads
    /// `--armtwin-config-extra` now, so a missing file fails before anything runs.
    pub(super) fn new(
        settings: Settings,
        bench: PathBuf,
        armtwin: PathBuf,
        work_dir: PathBuf,
    ) -> Result<Self> {
        let config_extra = match &settings.armtwin_config_extra {
            Some(path) => std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?,
            None => String::new(),
        };
        Ok(Self {
            settings,
            clock_origin_s: super::unix_now_s(),
            bench,
            armtwin,
            config_extra,
            work_dir,
        })
    }

    pub(super) fn start_echo(&self, robots: usize, lazy: bool) -> Result<SystemUnderTest> {
        let port = free_port()?;
        let endpoint = net::loopback_endpoint(port);
        let mut child = Command::new(&self.bench)
            .args(["echo", "-l", &endpoint, "--robots", &robots.to_string()])
            .args(lazy.then_some("--lazy"))
            .args(self.settings.paired.then_some("--paired"))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting {}", self.bench.display()))?;
        let stdout = child.stdout.take().context("echo stdout")?;
        let mut line = String::new();
        BufReader::new(stdout).read_line(&mut line)?;
        if line.trim() != "ready" {
            let _ = child.kill();
            bail!("the echo did not start: {line:?}");
        }
        wait_listening(port, &mut child)?;
        Ok(SystemUnderTest { child, endpoint })
    }

    /// `armtwin serve` with `config` (a file name in the work directory, written with `text`;
    /// with `--paired`, its poses and deviations paired).
    pub(super) fn start_armtwin_with(&self, config: &str, text: &str) -> Result<SystemUnderTest> {
        let text = if self.settings.paired {
            text.replacen("[service]\n", "[service]\noutputs = \"paired\"\n", 1)
        } else {
            text.to_owned()
        };
        SystemUnderTest::armtwin(
            &self.armtwin,
            &self.work_dir.join(config),
            &with_config_extra(&text, &self.config_extra),
        )
    }

    pub(super) fn start_armtwin(
        &self,
        robots: usize,
        encoding: WireEncoding,
    ) -> Result<SystemUnderTest> {
        self.start_armtwin_with(
            &format!("armtwin-{robots}-{}.toml", encoding.as_str()),
            &service_config_encoded(robots, encoding.as_str()),
        )
    }

    pub(super) fn load(
        &self,
        sut: &SystemUnderTest,
        target: Target,
        encoding: WireEncoding,
        extra: &[String],
    ) -> Result<LoadReport> {
        let target_name = target_name(target);
        // One file per system under test: binary messages' gateway `seq` goes on from one load
        // process to the next.
        let seq_file = self
            .work_dir
            .join(format!("seq-{target_name}-{}.json", sut.pid()));
        let output = load_command(
            &self.bench,
            sut,
            target,
            encoding,
            self.clock_origin_s,
            &seq_file,
        )
        .args(extra)
        .args(self.settings.paired.then_some("--paired"))
        .stdin(Stdio::null())
        .stderr(Stdio::inherit())
        .output()
        .context("running the load generator")?;
        if !output.status.success() {
            bail!("the load generator failed: {}", output.status);
        }
        serde_json::from_slice(&output.stdout).context("reading the load generator's report")
    }

    /// The load's flags of a latency run.
    pub(super) fn latency_flags(&self) -> [String; 4] {
        let s = &self.settings;
        [
            "--latency-rate".into(),
            s.latency_rate.to_string(),
            "--latency-duration".into(),
            s.latency_duration_s.to_string(),
        ]
    }

    /// Load arguments for `robots` over `gateways` sessions: a latency run only, or the search
    /// from `start_rate` (and the fleet check).
    pub(super) fn load_args(
        &self,
        robots: usize,
        gateways: u16,
        latency: bool,
        start_rate: f64,
        fleet_rate: Option<f64>,
    ) -> Vec<String> {
        let s = &self.settings;
        let mut args: Vec<String> = vec![
            "--robots".into(),
            robots.to_string(),
            "--gateways".into(),
            gateways.to_string(),
        ];
        if s.embedded {
            args.push("--embedded".into());
        }
        if latency {
            args.extend(self.latency_flags());
            return args;
        }
        args.extend([
            "--start-rate".into(),
            start_rate.to_string(),
            "--max-rate".into(),
            s.max_rate.to_string(),
            "--duration".into(),
            s.duration_s.to_string(),
            "--bisect-steps".into(),
            s.bisect_steps.to_string(),
            "--retries".into(),
            s.retries.to_string(),
        ]);
        if let Some(rate) = fleet_rate {
            args.extend([
                "--check-rate".into(),
                rate.to_string(),
                "--check-duration".into(),
                s.fleet_duration_s.to_string(),
                "--check-embedded".into(),
            ]);
        }
        args
    }

    /// Latency rounds `rounds` with the load's `args`, alternated between the two systems (each
    /// idle while the other is measured), so that both see the same machine: the echo's rounds
    /// and armtwin's.
    fn alternated(
        &self,
        (echo, armtwin): (&SystemUnderTest, &SystemUnderTest),
        encoding: WireEncoding,
        args: &[String],
        rounds: std::ops::Range<u32>,
        label: &str,
    ) -> Result<(Vec<Latency>, Vec<Latency>)> {
        let (mut echo_rounds, mut armtwin_rounds) = (Vec::new(), Vec::new());
        for round in rounds {
            eprintln!("== {label} round {round}, echo then armtwin serve");
            echo_rounds.extend(self.load(echo, Target::Echo, encoding, args)?.latency);
            armtwin_rounds.extend(self.load(armtwin, Target::Armtwin, encoding, args)?.latency);
        }
        Ok((echo_rounds, armtwin_rounds))
    }

    /// Both systems run side by side (each idle while the other is measured): latency rounds
    /// alternate between them, so that both see the same machine; then each one's search, the
    /// echo's from `start_rate`, armtwin's from half the echo's result. The last latency round
    /// runs in the load process of the search, which saves each system a load process's start
    /// and its declarations.
    pub(super) fn compare(
        &self,
        robots: usize,
        encoding: WireEncoding,
        gateways: u16,
        start_rate: f64,
        fleet_rate: Option<f64>,
    ) -> Result<Comparison> {
        let row = format!(
            "{robots} robots, {}, {gateways} gateways",
            encoding.as_str()
        );
        let echo_sut = self.start_echo(robots, false)?;
        let armtwin_sut = self.start_armtwin(robots, encoding)?;
        let latency_args = self.load_args(robots, gateways, true, 0.0, None);
        let (mut echo_rounds, mut armtwin_rounds) = self.alternated(
            (&echo_sut, &armtwin_sut),
            encoding,
            &latency_args,
            1..self.settings.latency_rounds,
            &format!("{row}: latency"),
        )?;
        let throughput = |report: &LoadReport| {
            report
                .search
                .as_ref()
                .map_or(0.0, |search| search.max_sustained_rate)
        };
        // The last latency round, then the search.
        let with_latency = |mut search_args: Vec<String>| {
            if self.settings.latency_rounds > 0 {
                search_args.extend(self.latency_flags());
            }
            search_args
        };
        eprintln!("== {row}: echo latency and throughput");
        let echo_args =
            with_latency(self.load_args(robots, gateways, false, start_rate, fleet_rate));
        let echo = self.load(&echo_sut, Target::Echo, encoding, &echo_args)?;
        echo_sut.stop();
        echo_rounds.extend(echo.latency.clone());
        eprintln!("== {row}: armtwin serve latency and throughput");
        let armtwin_start = if throughput(&echo) > 0.0 {
            (throughput(&echo) / 2.0).round()
        } else {
            start_rate
        };
        let armtwin_args =
            with_latency(self.load_args(robots, gateways, false, armtwin_start, fleet_rate));
        let armtwin = self.load(&armtwin_sut, Target::Armtwin, encoding, &armtwin_args)?;
        armtwin_sut.stop();
        armtwin_rounds.extend(armtwin.latency.clone());
        let cpu_per_sample = |report: &LoadReport| {
            let search = report.search.as_ref()?;
            let best = search
                .trials
                .iter()
                .filter(|trial| trial.sustained)
                .max_by(|a, b| a.offered_rate.total_cmp(&b.offered_rate))?;
            Some(best.sut_cpu_s? * 1e6 / best.samples as f64)
        };
        let echo_latency = LatencySummary::of(echo_rounds);
        let armtwin_latency = LatencySummary::of(armtwin_rounds);
        Ok(Comparison {
            robots,
            encoding,
            gateways,
            echo_throughput: throughput(&echo),
            armtwin_throughput: throughput(&armtwin),
            throughput_ratio: throughput(&armtwin) / throughput(&echo),
            added_latency_p99_us: armtwin_latency.p99_us - echo_latency.p99_us,
            echo_cpu_us_per_sample: cpu_per_sample(&echo),
            armtwin_cpu_us_per_sample: cpu_per_sample(&armtwin),
            echo_latency,
            armtwin_latency,
            echo,
            armtwin,
        })
    }

    /// Robots new to a freshly started echo (`--lazy`) and armtwin, at `rate` for a few
    /// seconds, every reply awaited.
    pub(super) fn first_contact(&self, rate: f64) -> Result<FirstContact> {
        let s = &self.settings;
        let (robots, encoding, gateways) = (
            s.first_contact_robots,
            s.last_encoding(),
            s.first_gateways(),
        );
        let args: Vec<String> = vec![
            "--robots".into(),
            robots.to_string(),
            "--gateways".into(),
            gateways.to_string(),
            "--first-contact-rate".into(),
            rate.to_string(),
            "--first-contact-duration".into(),
            s.first_contact_duration_s.to_string(),
        ];
        let trial = |sut: SystemUnderTest, target: Target| -> Result<Trial> {
            let trial = self
                .load(&sut, target, encoding, &args)?
                .first_contact
                .context("the load ran no first-contact trial")?;
            sut.stop();
            Ok(trial)
        };
        eprintln!("== first contact: {robots} new robots at {rate:.0} samples/s, echo --lazy");
        let echo = trial(self.start_echo(robots, true)?, Target::Echo)?;
        eprintln!("== first contact: armtwin serve");
        let armtwin = trial(self.start_armtwin(robots, encoding)?, Target::Armtwin)?;
        let echo_delivered_rate = echo.delivered_rate.unwrap_or(0.0);
        let armtwin_delivered_rate = armtwin.delivered_rate.unwrap_or(0.0);
        Ok(FirstContact {
            robots,
            encoding,
            gateways,
            rate,
            echo_delivered_rate,
            armtwin_delivered_rate,
            ratio: armtwin_delivered_rate / echo_delivered_rate,
            echo,
            armtwin,
        })
    }

    /// A plant's load on both systems side by side (each idle while the other is measured):
    /// every robot at `paced_hz` with its measured pose embedded, in the last encoding over the
    /// first gateway count. One unmeasured round each first (armtwin declares a streaming
    /// robot's route caches once it has seen it stream, the echo up front), then alternated
    /// rounds, as many as latency rounds.
    pub(super) fn paced(&self) -> Result<Paced> {
        let s = &self.settings;
        let (robots, encoding, gateways) = (s.paced_robots, s.last_encoding(), s.first_gateways());
        let rate = s.paced_hz * robots as f64;
        let args = |duration_s: f64| -> Vec<String> {
            vec![
                "--robots".into(),
                robots.to_string(),
                "--gateways".into(),
                gateways.to_string(),
                "--embedded".into(),
                "--latency-rate".into(),
                rate.to_string(),
                "--latency-duration".into(),
                duration_s.to_string(),
            ]
        };
        let row = format!("paced: {robots} robots × {} Hz", s.paced_hz);
        let echo_sut = self.start_echo(robots, false)?;
        let armtwin_sut = self.start_armtwin(robots, encoding)?;
        eprintln!("== {row}: one unmeasured round each");
        let warm_up = args(s.paced_duration_s.min(PACED_WARM_UP_S));
        self.load(&echo_sut, Target::Echo, encoding, &warm_up)?;
        self.load(&armtwin_sut, Target::Armtwin, encoding, &warm_up)?;
        let (echo_rounds, armtwin_rounds) = self.alternated(
            (&echo_sut, &armtwin_sut),
            encoding,
            &args(s.paced_duration_s),
            1..s.latency_rounds.max(1) + 1,
            &format!("{row}:"),
        )?;
        echo_sut.stop();
        armtwin_sut.stop();
        let cores = |rounds: &[Latency]| {
            median(
                rounds
                    .iter()
                    .filter_map(|l| Some(l.trial.sut_cpu_s? / l.trial.duration_s))
                    .collect(),
            )
        };
        let lost = |rounds: &[Latency]| rounds.iter().map(|l| l.trial.lost).sum();
        let (echo_cores, armtwin_cores) = (cores(&echo_rounds), cores(&armtwin_rounds));
        let (echo_lost, armtwin_lost) = (lost(&echo_rounds), lost(&armtwin_rounds));
        let echo_latency = LatencySummary::of(echo_rounds);
        let armtwin_latency = LatencySummary::of(armtwin_rounds);
        Ok(Paced {
            robots,
            hz_per_robot: s.paced_hz,
            rate,
            encoding,
            gateways,
            duration_s: s.paced_duration_s,
            echo_cores,
            armtwin_cores,
            cpu_ratio: armtwin_cores / echo_cores,
            p99_ratio: armtwin_latency.p99_us / echo_latency.p99_us,
            echo_lost,
            armtwin_lost,
            echo_latency,
            armtwin_latency,
        })
    }

    /// Every row: each robot count in each encoding over the first gateway count, then the
    /// largest robot count in the last encoding over each further gateway count; the fleet
    /// check (at `fleet_rate`) in `fleet_row`.
    pub(super) fn compare_rows(
        &self,
        fleet_row: (usize, WireEncoding, u16),
        fleet_rate: Option<f64>,
    ) -> Result<Vec<Comparison>> {
        let settings = &self.settings;
        let largest = settings.robots.iter().copied().max().unwrap_or(1);
        let mut rows: Vec<(usize, WireEncoding, u16)> = Vec::new();
        for &encoding in &settings.encodings {
            for &robots in &settings.robots {
                rows.push((robots, encoding, settings.first_gateways()));
            }
        }
        for &gateways in settings.gateways.iter().skip(1) {
            rows.push((largest, settings.last_encoding(), gateways));
        }
        let mut by_robots: Vec<Comparison> = Vec::new();
        for &(robots, encoding, gateways) in &rows {
            let fleet = fleet_rate.filter(|_| (robots, encoding, gateways) == fleet_row);
            // The echo's search starts at its last result in the same encoding, where the next
            // row's usually is (fewer doubling trials than from the start rate).
            let start_rate = by_robots
                .iter()
                .rev()
                .find(|c| c.encoding == encoding && c.echo_throughput > 0.0)
                .map_or(settings.start_rate, |c| c.echo_throughput);
            by_robots.push(self.compare(robots, encoding, gateways, start_rate, fleet)?);
        }
        Ok(by_robots)
    }
}
