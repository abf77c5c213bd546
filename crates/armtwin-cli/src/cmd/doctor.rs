//! `armtwin doctor`: a configuration checked before it runs, one line per check (`OK`, `WARN`,
//! `FAIL`): each configured robot's model, calibration and tool, the controllers `serve` would
//! stream (their RTDE and dashboard ports, the model they say), who may reach each door, and the
//! recorder's folder. Exits 1 when a check fails.
//!
//! Owns the checks' I/O (connecting, writing a probe file) and the printing; who may reach a door
//! is the library's ([`armtwin_service::exposure`]), what a controller's model means the mesh's
//! ([`ControllerFacts`]).
#![allow(clippy::print_stdout, reason = "the report is the command's output")]

use std::fmt::Write as _;
use std::path::Path;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use armtwin_codec::rtde::RtdeSample;
use armtwin_core::kinematics::{OutputFrame, TcpOffset};
use armtwin_gateway::{ControllerSettings, dashboard};
use armtwin_mesh::controller::ControllerFacts;
use armtwin_service::config::{Overrides, RtdeLink, ServiceConfig};
use armtwin_service::exposure::{self, Verdict};

use crate::flags::DoctorArgs;

/// The lines so far, and how many failed.
#[derive(Default)]
struct Report {
    text: String,
    failed: usize,
    warned: usize,
}

impl Report {
    fn line(&mut self, verdict: Verdict, check: &str, detail: &str) {
        let word = match verdict {
            Verdict::Ok => "OK",
            Verdict::Warn => {
                self.warned += 1;
                "WARN"
            }
            Verdict::Fail => {
                self.failed += 1;
                "FAIL"
            }
        };
        let _ = writeln!(self.text, "{word:<4} {check}: {detail}");
    }
}

pub(super) fn run(args: &DoctorArgs) -> Result<()> {
    let config = match ServiceConfig::load(args.config.as_deref(), &Overrides::default()) {
        Ok(config) => config,
        Err(e) => {
            println!("FAIL configuration: {e}");
            bail!("the configuration does not load");
        }
    };
    let mut report = Report::default();
    report.line(
        Verdict::Ok,
        "configuration",
        &format!("{} loads", config.source_name),
    );
    check_robots(&config, &mut report);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    for link in &config.rtde_links {
        runtime.block_on(check_controller(&config, link, &mut report));
    }
    for door in exposure::doors(&config)? {
        report.line(door.verdict, &door.name, &door.who);
    }
    check_recorder(&config, &mut report);
    if let Some(prometheus) = &args.prometheus {
        runtime.block_on(check_prometheus(&config, prometheus, &mut report));
    }
    print!("{}", report.text);
    println!("{} failed, {} to look at", report.failed, report.warned);
    if report.failed > 0 {
        bail!("{} checks failed", report.failed);
    }
    Ok(())
}

/// Each configured robot's model, calibration and tool.
fn check_robots(config: &ServiceConfig, report: &mut Report) {
    let mut ids: Vec<&String> = config.robots.keys().collect();
    ids.sort();
    if ids.is_empty() {
        report.line(
            Verdict::Ok,
            "robots",
            "none named: every robot takes [robots.default]",
        );
    }
    let streamed = |id: &str| config.rtde_links.iter().any(|link| link.robot == id);
    for id in ids {
        let model = &config.robots[id].model;
        let arm = &model.arm().name;
        let check = format!("robot {id}");
        match model.calibration() {
            Some(_) => report.line(Verdict::Ok, &check, &format!("{arm} with its calibration")),
            None => report.line(
                Verdict::Warn,
                &check,
                &format!(
                    "{arm} without a calibration: the twin computes the nominal arm, which a \
                     real one departs from by millimetres, often more than the 5-mm alarm \
                     (copy the controller's /root/.urcontrol/calibration.conf and name it in \
                     calibration; docs/troubleshooting.md#alarms-that-never-stop-no-calibration)"
                ),
            ),
        }
        let tool = if config.configured_tools.sets(id) {
            "the configuration's tcp"
        } else if streamed(id) {
            "its controller's (RTDE tcp_offset)"
        } else {
            "its gateway's controller facts, if it sends them; the flange until then"
        };
        report.line(Verdict::Ok, &format!("robot {id} tool"), tool);
    }
}

/// One controller `serve` would stream: its RTDE port, its dashboard server and the model it
/// says against the configured one.
async fn check_controller(config: &ServiceConfig, link: &RtdeLink, report: &mut Report) {
    let check = format!("controller of {}", link.robot);
    let controller = match ControllerSettings::at(&link.robot, &link.address) {
        Ok(mut controller) => {
            if let Some(port) = link.dashboard_port {
                controller.dashboard_port = port;
            }
            controller
        }
        Err(e) => {
            report.line(Verdict::Fail, &check, &e.to_string());
            return;
        }
    };
    let (host, port) = (controller.host.as_str(), controller.port);
    match armtwin_gateway::probe(host, port).await {
        Ok((started, sample)) => {
            let version = started.controller;
            report.line(
                Verdict::Ok,
                &check,
                &format!(
                    "RTDE at {host}:{port} streams (controller software {}.{}.{}.{}, protocol {})",
                    version.major,
                    version.minor,
                    version.bugfix,
                    version.build,
                    started.version.number()
                ),
            );
            if !started.dropped.is_empty() {
                report.line(
                    Verdict::Warn,
                    &check,
                    &format!("the controller lacks {}: streamed without them", started.dropped.join(", ")),
                );
            }
            compare_with_controller(config, &link.robot, &sample, report);
        }
        Err(e) => report.line(
            Verdict::Fail,
            &check,
            &format!("RTDE at {host}:{port}: {e} (is RTDE on, and port {port} open in every firewall between?)"),
        ),
    }
    let dashboard_port = controller.dashboard_port;
    let (identity, version) = match dashboard::read_identity_and_version(host, dashboard_port).await
    {
        Ok(read) => read,
        Err(e) => {
            report.line(
                Verdict::Fail,
                &check,
                &format!("dashboard server: {e}: the model and serial number cannot be checked"),
            );
            return;
        }
    };
    let configured = &config.robots[&link.robot].model.arm().name;
    let facts = ControllerFacts {
        version,
        model: identity.model.clone(),
        serial: identity.serial.clone(),
        ..ControllerFacts::default()
    };
    let says = format!(
        "'{}', serial number {}",
        identity.model.as_deref().unwrap_or("no model"),
        identity.serial.as_deref().unwrap_or("unknown")
    );
    match facts.model_agrees(configured) {
        Some(true) => report.line(
            Verdict::Ok,
            &check,
            &format!("dashboard server at {host}:{dashboard_port} says {says}: a {configured}, as configured"),
        ),
        Some(false) => report.line(
            Verdict::Fail,
            &check,
            &format!(
                "dashboard server at {host}:{dashboard_port} says {says}: a {}, the configuration says {configured}",
                facts.catalog_model().unwrap_or_default()
            ),
        ),
        None => report.line(
            Verdict::Warn,
            &check,
            &format!("dashboard server at {host}:{dashboard_port} says {says}: the model is not checked against {configured}"),
        ),
    }
}

/// The twin of `robot` against the controller's own TCP pose at the joints of its first data
/// package: the error a missing calibration or a wrong tool makes, measured, against the alarm.
fn compare_with_controller(
    config: &ServiceConfig,
    robot: &str,
    sample: &RtdeSample,
    report: &mut Report,
) {
    let check = format!("twin of {robot}");
    let settings = &config.robots[robot];
    let Some(measured) = sample.actual_tcp_pose else {
        report.line(
            Verdict::Warn,
            &check,
            "the controller sends no actual_TCP_pose: not compared",
        );
        return;
    };
    if settings.model.frame() != OutputFrame::Base {
        report.line(
            Verdict::Ok,
            &check,
            "frame base_link: not compared with RTDE's base-frame pose",
        );
        return;
    }
    // The tool the twin will use: the configuration's, else the controller's.
    let controller_tool = sample.tcp_offset.and_then(TcpOffset::from_ur_pose);
    let model = match controller_tool {
        Some(tool) if !config.configured_tools.sets(robot) => settings.model.with_tool(tool),
        _ => Ok((*settings.model).clone()),
    };
    let pose = match model
        .map_err(|e| e.to_string())
        .and_then(|model| model.pose(&sample.actual_q_rad).map_err(|e| e.to_string()))
    {
        Ok(pose) => pose,
        Err(e) => {
            report.line(
                Verdict::Fail,
                &check,
                &format!("the twin cannot be computed: {e}"),
            );
            return;
        }
    };
    let error_m = (0..3)
        .map(|axis| (pose.position_m[axis] - measured[axis]).powi(2))
        .sum::<f64>()
        .sqrt();
    let alarm_m = settings.alarm.position_m;
    let figure = format!(
        "{:.2} mm from the controller's own TCP pose at its current joints",
        error_m * 1e3
    );
    match alarm_m {
        Some(alarm_m) if error_m > alarm_m => report.line(
            Verdict::Warn,
            &check,
            &format!(
                "{figure}, above the {:.1}-mm alarm: the position alarm would stay on (a calibration or the tool missing?)",
                alarm_m * 1e3
            ),
        ),
        Some(alarm_m) => report.line(
            Verdict::Ok,
            &check,
            &format!("{figure} (alarm at {:.1} mm)", alarm_m * 1e3),
        ),
        None => report.line(Verdict::Ok, &check, &figure),
    }
}

/// The recorder's folder: made if missing, as the service makes it, and written to.
fn check_recorder(config: &ServiceConfig, report: &mut Report) {
    let recorder = &config.recorder;
    let anyone = recorder.enabled || recorder.robots.values().any(|on| *on);
    if !anyone {
        report.line(Verdict::Ok, "recorder", "off: no folder needed");
        return;
    }
    let dir = &recorder.store.dir;
    match probe_writable(dir) {
        Ok(()) => report.line(
            Verdict::Ok,
            "recorder",
            &format!("{} is writable", dir.display()),
        ),
        Err(e) => report.line(
            Verdict::Fail,
            "recorder",
            &format!(
                "{} cannot be written ({e}): no incident file would be kept",
                dir.display()
            ),
        ),
    }
}

fn probe_writable(dir: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let probe = dir.join(format!(".armtwin-doctor-{}", std::process::id()));
    std::fs::write(&probe, b"probe")?;
    std::fs::remove_file(&probe)
}

/// The alerting rules armtwin ships (`config/prometheus/alerts.yml`), by name.
const SHIPPED_RULES: &str = include_str!("../../../../config/prometheus/alerts.yml");

/// How long Prometheus may take to answer.
const PROMETHEUS_TIMEOUT: Duration = Duration::from_secs(5);

/// The most of an answer read: a Prometheus of many targets answers in megabytes.
const MAX_ANSWER_BYTES: usize = 16 << 20;

/// Whether the Prometheus at `base` scrapes this service's `/metrics`, under which job, and
/// whether it holds the shipped rules.
async fn check_prometheus(config: &ServiceConfig, base: &str, report: &mut Report) {
    let check = format!("prometheus {base}");
    let Some(listen) = config.http_listen else {
        report.line(
            Verdict::Warn,
            &check,
            "no [http] listen: this service serves no /metrics to scrape",
        );
        return;
    };
    let targets = match get_json(base, "/api/v1/targets?state=active").await {
        Ok(answer) => answer,
        Err(e) => {
            report.line(
                Verdict::Fail,
                &check,
                &format!("cannot read its targets: {e}"),
            );
            return;
        }
    };
    let port = format!(":{}/metrics", listen.port());
    let ours: Vec<&serde_json::Value> = targets["data"]["activeTargets"]
        .as_array()
        .map(|all| {
            all.iter()
                .filter(|t| {
                    t["scrapeUrl"]
                        .as_str()
                        .is_some_and(|url| url.ends_with(&port))
                })
                .collect()
        })
        .unwrap_or_default();
    if ours.is_empty() {
        report.line(
            Verdict::Fail,
            &check,
            &format!(
                "scrapes no /metrics on port {}: add a job for it (docs/alerts.md)",
                listen.port()
            ),
        );
    }
    for target in ours {
        let job = target["labels"]["job"].as_str().unwrap_or("?");
        let url = target["scrapeUrl"].as_str().unwrap_or("?");
        let health = target["health"].as_str().unwrap_or("unknown");
        if health != "up" && health != "unknown" {
            let error = target["lastError"].as_str().unwrap_or("");
            report.line(
                Verdict::Fail,
                &check,
                &format!("job '{job}' scrapes {url}, which is {health}: {error}"),
            );
        } else if job == "armtwin" {
            report.line(Verdict::Ok, &check, &format!("job 'armtwin' scrapes {url}"));
        } else {
            report.line(
                Verdict::Warn,
                &check,
                &format!(
                    "job '{job}' scrapes {url}: ArmtwinDown reads up{{job=\"armtwin\"}}, so name \
                     the job armtwin or change that rule"
                ),
            );
        }
    }
    check_rules(base, &check, report).await;
}

/// Whether the Prometheus at `base` holds the shipped alerting rules.
async fn check_rules(base: &str, check: &str, report: &mut Report) {
    let rules = match get_json(base, "/api/v1/rules?type=alert").await {
        Ok(answer) => answer,
        Err(e) => {
            report.line(Verdict::Fail, check, &format!("cannot read its rules: {e}"));
            return;
        }
    };
    let loaded: std::collections::BTreeSet<&str> = rules["data"]["groups"]
        .as_array()
        .into_iter()
        .flatten()
        .flat_map(|group| group["rules"].as_array().into_iter().flatten())
        .filter_map(|rule| rule["name"].as_str())
        .collect();
    let shipped: Vec<&str> = SHIPPED_RULES
        .lines()
        .filter_map(|line| line.trim().strip_prefix("- alert: "))
        .collect();
    let missing: Vec<&str> = shipped
        .iter()
        .copied()
        .filter(|name| !loaded.contains(name))
        .collect();
    if missing.is_empty() {
        report.line(
            Verdict::Ok,
            check,
            &format!("holds armtwin's {} alerting rules", shipped.len()),
        );
    } else {
        report.line(
            Verdict::Warn,
            check,
            &format!(
                "lacks {} of armtwin's {} alerting rules ({}): load config/prometheus/alerts.yml",
                missing.len(),
                shipped.len(),
                missing.join(", ")
            ),
        );
    }
}

/// `base` (`http://HOST:PORT`) `path`'s JSON answer, within [`PROMETHEUS_TIMEOUT`] and
/// [`MAX_ANSWER_BYTES`].
async fn get_json(base: &str, path: &str) -> Result<serde_json::Value, String> {
    use http_body_util::{BodyExt as _, Empty, Limited};
    let authority = base
        .strip_prefix("http://")
        .ok_or("give http://HOST:PORT (a Prometheus behind TLS is not read here)")?
        .trim_end_matches('/');
    let exchange = async {
        let stream = tokio::net::TcpStream::connect(authority)
            .await
            .map_err(|e| e.to_string())?;
        let (mut sender, connection) =
            hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(stream))
                .await
                .map_err(|e| e.to_string())?;
        tokio::spawn(connection);
        let request = hyper::Request::get(path)
            .header(hyper::header::HOST, authority)
            .body(Empty::<hyper::body::Bytes>::new())
            .map_err(|e| e.to_string())?;
        let response = sender
            .send_request(request)
            .await
            .map_err(|e| e.to_string())?;
        let status = response.status();
        let body = Limited::new(response.into_body(), MAX_ANSWER_BYTES)
            .collect()
            .await
            .map_err(|e| e.to_string())?
            .to_bytes();
        if !status.is_success() {
            return Err(format!("{path}: HTTP {status}"));
        }
        serde_json::from_slice(&body).map_err(|e| format!("{path}: {e}"))
    };
    tokio::time::timeout(PROMETHEUS_TIMEOUT, exchange)
        .await
        .map_err(|_| format!("no answer within {PROMETHEUS_TIMEOUT:?}"))?
}
