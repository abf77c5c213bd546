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
