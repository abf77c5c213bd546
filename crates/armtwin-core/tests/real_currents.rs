//! The effort monitor on a real arm's currents: a UR3e's RTDE recording
//! (`tests/data/ur3e_rad_program.csv`, 25 Hz, normal program motion, nothing touching it) raises no alarm, its
//! friction and payload come out physical, and contacts injected into its measured currents are
//! detected. `-- --nocapture` prints the figures docs/load-twin.md quotes.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]
#![allow(
    clippy::cast_precision_loss,
    reason = "sample and contact counts far below 2⁵³"
)]

use armtwin_core::dynamics::monitor::{
    DetectionSource, EffortAlarm, EffortConfig, EffortMonitor, ThresholdSource,
};
use armtwin_core::dynamics::payload::{PayloadIdentification, PayloadIdentifier};
use armtwin_core::dynamics::{ArmDynamics, ur};
use armtwin_core::model::catalog;
use armtwin_core::sample::{JointQuantity, JointState, Payload};

const J: usize = 6;
const RECORDING: &str = include_str!("../../../tests/data/ur3e_rad_program.csv");
/// What the controller was configured to carry (the recording's `payload`, kg).
const CONFIGURED_KG: f64 = 1.07;
/// Seconds of the recording the thresholds are learnt from in the contact test: its first half.
const LEARNING_S: f64 = 17.0;

/// One RTDE row, the columns the monitor reads.
#[derive(Debug, Clone)]
struct Row {
    t_s: f64,
    target_q: [f64; J],
    target_qd: [f64; J],
    target_qdd: [f64; J],
    target_current: [f64; J],
    target_moment: [f64; J],
    q: [f64; J],
    qd: [f64; J],
    current: [f64; J],
    temperature: [f64; J],
    payload_kg: f64,
    payload_cog_m: [f64; 3],
}

fn recording() -> Vec<Row> {
    let mut lines = RECORDING.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let at = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("column {name}"))
    };
    let six = |cells: &[&str], group: &str| -> [f64; J] {
        std::array::from_fn(|k| cells[at(&format!("{group}_{k}"))].parse().unwrap())
    };
    lines
        .map(|line| {
            let cells: Vec<&str> = line.split(',').collect();
            let value = |name: &str| -> f64 { cells[at(name)].parse().unwrap() };
            Row {
                t_s: value("timestamp"),
                target_q: six(&cells, "target_q"),
                target_qd: six(&cells, "target_qd"),
                target_qdd: six(&cells, "target_qdd"),
                target_current: six(&cells, "target_current"),
                target_moment: six(&cells, "target_moment"),
                q: six(&cells, "actual_q"),
                qd: six(&cells, "actual_qd"),
                current: six(&cells, "actual_current"),
                temperature: six(&cells, "joint_temperatures"),
                payload_kg: value("payload"),
                payload_cog_m: [
                    value("payload_cog_0"),
                    value("payload_cog_1"),
                    value("payload_cog_2"),
                ],
            }
        })
        .collect()
}

/// What the gateway hands the twin for `row`, with `extra_nm` added to the measured currents
/// (through the drives' torque factors): a contact.
fn joint_state(row: &Row, extra_nm: &[f64; J]) -> JointState {
    let factors = ur::current_to_torque_nm_per_a("ur3e").unwrap();
    let current: [f64; J] = std::array::from_fn(|k| row.current[k] + extra_nm[k] / factors[k]);
    let mut state = JointState::new(J);
    state.set(JointQuantity::Velocity, &row.qd);
    state.set(JointQuantity::TargetPosition, &row.target_q);
    state.set(JointQuantity::TargetVelocity, &row.target_qd);
    state.set(JointQuantity::TargetAcceleration, &row.target_qdd);
    state.set(JointQuantity::Current, &current);
    state.set(JointQuantity::TargetCurrent, &row.target_current);
    state.set(JointQuantity::Temperature, &row.temperature);
    state.payload = Some(Payload {
        mass_kg: row.payload_kg,
        cog_m: row.payload_cog_m,
        inertia_kg_m2: None,
    });
    state
}

fn monitor(learning_s: f64) -> EffortMonitor {
    let arm = catalog::arm("ur3e").unwrap();
    let config = EffortConfig {
        threshold_learning_s: learning_s,
        ..EffortConfig::default()
    };
    EffortMonitor::new(&arm, &config, 10.0).unwrap()
}

/// Steps `monitor` over `rows`; the alarm changes with their stamps.
fn run(monitor: &mut EffortMonitor, rows: &[Row]) -> Vec<(f64, EffortAlarm)> {
    let mut alarms = Vec::new();
    for row in rows {
        monitor.step(row.t_s, &row.q, &joint_state(row, &[0.0; J]), |alarm| {
            alarms.push((row.t_s, alarm));
        });
    }
    alarms
}

fn rms(values: &[[f64; J]]) -> [f64; J] {
    std::array::from_fn(|k| {
        (values.iter().map(|v| v[k] * v[k]).sum::<f64>() / values.len() as f64).sqrt()
    })
}

fn show(values: &[f64]) -> String {
    values
        .iter()
        .map(|v| format!("{v:6.2}"))
        .collect::<Vec<_>>()
        .join(" ")
}

#[test]
fn normal_motion_raises_no_alarm_with_thresholds_learnt_or_learning() {
    let rows = recording();
    let hours = (rows.last().unwrap().t_s - rows[0].t_s) / 3600.0;
    for learning_s in [LEARNING_S, EffortConfig::default().threshold_learning_s] {
        let mut monitor = monitor(learning_s);
        let alarms = run(&mut monitor, &rows);
        let summary = monitor.summary();
        println!(
            "learning {learning_s} s: {} thresholds {} N·m, {} alarms in {:.4} h",
            summary.threshold_source.as_str(),
            show(&summary.collision_threshold_nm),
            alarms.len(),
            hours
        );
        assert!(alarms.is_empty(), "{alarms:?}");
        assert_eq!(summary.detection, DetectionSource::TargetCurrent);
        let expected = if learning_s < 35.0 {
            ThresholdSource::Learned
        } else {
            ThresholdSource::Learning
        };
        assert_eq!(summary.threshold_source, expected);
    }
}

/// Per joint RMS of each residual the monitor could watch, on the whole recording: measured torque
/// less our model; less the friction fitted too; and measured less target current.
#[test]
fn each_residual_term_pays_on_real_currents() {
    let rows = recording();
    let factors = ur::current_to_torque_nm_per_a("ur3e").unwrap();
    let mut monitor = monitor(0.0);
    let (mut model_only, mut with_friction, mut target_current) = (vec![], vec![], vec![]);
    for row in &rows {
        let readout = monitor
            .step(row.t_s, &row.q, &joint_state(row, &[0.0; J]), |_| {})
            .unwrap();
        let measured = readout.measured_nm.unwrap();
        model_only.push(std::array::from_fn(|k| measured[k] - readout.model_nm[k]));
        with_friction.push(readout.residual_nm.unwrap().to_array::<J>().unwrap());
        target_current.push(std::array::from_fn(|k| {
            (row.current[k] - row.target_current[k]) * factors[k]
        }));
    }
    // The friction fit needs its samples first: compare where every joint's fit is in use, the
    // last quarter.
    let tail = rows.len() * 3 / 4;
    let [model_only, with_friction, target_current] =
        [&model_only, &with_friction, &target_current].map(|v| rms(&v[tail..]));
    println!("residual RMS (N·m), last quarter of the recording, joints 1–6:");
    println!("  currents − model               {}", show(&model_only));
    println!("  currents − model − friction    {}", show(&with_friction));
    println!("  currents − target current      {}", show(&target_current));
    // On the joints that move most (1–4) friction pays, and the target current alone removes
    // more than half of what our model leaves.
    for k in 0..4 {
        assert!(with_friction[k] < 0.7 * model_only[k], "{k}");
        assert!(target_current[k] < 0.5 * model_only[k], "{k}");
    }
}

/// At rest the controller's target current carries no friction feed-forward: its ratio to
/// `target_moment` is the controller's own current-to-torque factor, which the nominal `K_τ · 101`
/// must match.
#[test]
fn the_nominal_torque_factors_match_the_controllers_own() {
    let rows = recording();
    let factors = ur::current_to_torque_nm_per_a("ur3e").unwrap();
    let rest: Vec<&Row> = rows
        .iter()
        .filter(|row| row.target_qd.iter().all(|v| *v == 0.0))
        .collect();
    for (k, nominal) in factors.iter().enumerate() {
        let held: Vec<_> = rest
            .iter()
            .filter(|row| row.target_current[k].abs() > 0.05)
            .collect();
        if held.len() < 10 {
            continue;
        }
        // Least squares through the origin: moment = factor · current.
        let factor = held
            .iter()
            .map(|row| row.target_moment[k] * row.target_current[k])
            .sum::<f64>()
            / held
                .iter()
                .map(|row| row.target_current[k].powi(2))
                .sum::<f64>();
        println!(
            "joint {}: controller {factor:.4} N·m/A, nominal {nominal:.4} ({} rows at rest)",
            k + 1,
            held.len()
        );
        assert!(
            (factor / nominal - 1.0).abs() < 0.03,
            "{k}: {factor} vs {nominal}"
        );
    }
}

#[test]
fn friction_fits_are_physical() {
    let rows = recording();
    let mut monitor = monitor(0.0);
    run(&mut monitor, &rows);
    let summary = monitor.summary();
    for (k, friction) in summary.friction.iter().enumerate() {
        println!("joint {}: {friction:?}", k + 1);
        if let Some(friction) = friction {
            assert!(friction.coulomb_nm >= 0.0, "{k}: {friction:?}");
            assert!(friction.viscous_nm_s_rad >= 0.0, "{k}: {friction:?}");
        }
    }
    // Joints 1–5 move enough to be fitted; wrist 3 barely turns in this recording.
    assert!(summary.friction[..5].iter().all(Option::is_some));
}

#[test]
fn the_payload_is_physical_or_not_identifiable() {
    let rows = recording();
    let mut monitor = monitor(0.0);
    let alarms = run(&mut monitor, &rows);
    assert!(
        !alarms
            .iter()
            .any(|(_, alarm)| matches!(alarm, EffortAlarm::Payload { .. })),
        "{alarms:?}"
    );
    let live = monitor.summary().payload.identification;
    // The same rows offline, every rest sample at once, no forgetting.
    let arm = ArmDynamics::<J>::from_arm(&catalog::arm("ur3e").unwrap()).unwrap();
    let factors = ur::current_to_torque_nm_per_a("ur3e").unwrap();
    let mut identifier = PayloadIdentifier::new();
    for row in rows.iter().filter(|row| {
        row.qd.iter().all(|v| v.abs() < 0.01) && row.target_qdd.iter().all(|a| a.abs() < 0.1)
    }) {
        let gravity = arm.gravity_nm(&row.q);
        let beyond: [f64; J] = std::array::from_fn(|k| row.current[k] * factors[k] - gravity[k]);
        identifier.add_static_sample(&arm, &row.q, &beyond);
    }
    let configured_cog = rows[0].payload_cog_m;
    let offline = identifier.identify(EffortConfig::default().payload_reach_m, configured_cog);
    println!(
        "centre of gravity unconstrained: {:?}",
        identifier.identify(f64::INFINITY, configured_cog)
    );
    for (name, identification) in [("live", live.unwrap()), ("offline", offline)] {
        println!("{name}: {identification:?}");
        match identification {
            PayloadIdentification::Identified(estimate) => {
                assert!(estimate.mass_kg >= 0.0, "{estimate:?}");
                assert!(
                    (estimate.mass_kg - CONFIGURED_KG).abs() <= 0.3,
                    "{estimate:?}"
                );
            }
            PayloadIdentification::NotIdentifiable { .. } => {}
        }
    }
}

/// A contact: onset (s, a sample's stamp), joint, torque (N·m), duration (s).
type Contact = (f64, usize, f64, f64);

#[test]
fn contacts_injected_into_real_currents_are_detected() {
    let rows = recording();
    let mut learnt = monitor(LEARNING_S);
    let split = rows
        .iter()
        .position(|row| row.t_s - rows[0].t_s > LEARNING_S + 1.0)
        .unwrap();
    let alarms = run(&mut learnt, &rows[..split]);
    assert!(alarms.is_empty(), "{alarms:?}");
    let summary = learnt.summary();
    assert_eq!(summary.threshold_source, ThresholdSource::Learned);
    let thresholds = summary.collision_threshold_nm;

    // Onsets every 1.2 s over the second half; per joint, durations 20–200 ms, signs alternating.
    let mut contacts: Vec<Contact> = Vec::new();
    for (joint, threshold_nm) in thresholds.iter().enumerate() {
        for (n, start) in (split..rows.len() - 15).step_by(30).enumerate() {
            for duration_s in [0.02, 0.06, 0.1, 0.2] {
                let sign = if n % 2 == 0 { 1.0 } else { -1.0 };
                contacts.push((
                    rows[start].t_s,
                    joint,
                    sign * 2.0 * threshold_nm,
                    duration_s,
                ));
            }
        }
    }
    let mut detected = [0_u32; J];
    let mut offered = [0_u32; J];
    let mut latencies_s: Vec<f64> = Vec::new();
    let mut false_alarms = 0_u32;
    for &(onset_s, joint, torque_nm, duration_s) in &contacts {
        // The learnt monitor, run clean to the contact, then through it and 0.4 s beyond.
        let mut monitor = learnt.clone();
        let mut hit = None;
        for row in rows[split..]
            .iter()
            .filter(|row| row.t_s < onset_s + duration_s + 0.4)
        {
            let mut extra = [0.0; J];
            if row.t_s >= onset_s && row.t_s < onset_s + duration_s {
                extra[joint] = torque_nm;
            }
            monitor.step(row.t_s, &row.q, &joint_state(row, &extra), |alarm| {
                if let EffortAlarm::Collision {
                    joint: k, on: true, ..
                } = alarm
                {
                    if k == joint && row.t_s >= onset_s && hit.is_none() {
                        hit = Some(row.t_s - onset_s);
                    } else {
                        false_alarms += 1;
                    }
                }
            });
        }
        offered[joint] += 1;
        if let Some(latency_s) = hit {
            detected[joint] += 1;
            latencies_s.push(latency_s);
        }
    }
    let rate: [f64; J] = std::array::from_fn(|k| f64::from(detected[k]) / f64::from(offered[k]));
    latencies_s.sort_by(f64::total_cmp);
    let median_ms = 1000.0 * latencies_s[latencies_s.len() / 2];
    let max_ms = 1000.0 * latencies_s.last().unwrap();
    println!(
        "thresholds learnt on the first {LEARNING_S} s (N·m): {}",
        show(&thresholds)
    );
    println!(
        "contacts of 2× threshold, 20–200 ms, per joint: {offered:?} offered, {detected:?} detected"
    );
    println!("detection rate per joint: {}", show(&rate));
    println!(
        "latency from onset: median {median_ms:.0} ms, max {max_ms:.0} ms (25 Hz samples); false alarms {false_alarms}"
    );
    for (k, rate) in rate.iter().enumerate() {
        assert!(*rate >= 0.95, "joint {}: {rate}", k + 1);
    }
    assert_eq!(false_alarms, 0);
    // Detected within two samples at 25 Hz.
    assert!(max_ms <= 80.0 + 1e-6, "{max_ms}");
}
