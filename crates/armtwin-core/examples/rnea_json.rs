//! The core's inverse dynamics as a line filter, for the Python reference tests
//! (`tests/python/test_dynamics_reference.py`, against Pinocchio): one state per input line, one
//! JSON object per output line, every number printed with Rust's shortest round-trip form.
//!
//! Input line, whitespace-separated: `ARM q… qd… qdd… payload_mass cog_x cog_y cog_z Ixx Iyy Izz
//! Ixy Ixz Iyz g_x g_y g_z`, with `ARM` a catalog name or the path of a custom arm's TOML (with a
//! `[dynamics]` section) and one value per joint in each of `q`, `qd`, `qdd` (6 or 7 joints).
//! Output: `tau` (inverse dynamics), `gravity`, `coriolis` (`C q̇`), `mass_matrix` (rows),
//! `momentum` and `coriolis_transpose_qd`.
//!
//! `cargo run -p armtwin-core --example rnea_json <<< "ur5e 0 0 0 0 0 0 …"`; `cargo test` builds it
//! into `target/debug/examples/`.
#![allow(
    clippy::print_stdout,
    reason = "a line filter: its output is the point"
)]

use std::error::Error;
use std::io::{BufRead, Write};

use armtwin_core::dynamics::{ArmDynamics, Payload};
use armtwin_core::model::{ArmDescription, catalog, custom};

fn main() -> Result<(), Box<dyn Error>> {
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    for line in std::io::stdin().lock().lines() {
        let line = line?;
        let mut fields = line.split_whitespace();
        let Some(arm_name) = fields.next() else {
            continue;
        };
        let arm = load_arm(arm_name)?;
        let values = fields
            .map(str::parse::<f64>)
            .collect::<Result<Vec<_>, _>>()?;
        let json = match arm.dh.len() {
            6 => evaluate::<6>(&arm, &values)?,
            7 => evaluate::<7>(&arm, &values)?,
            other => return Err(format!("{arm_name}: {other} joints; 6 or 7 supported").into()),
        };
        writeln!(out, "{json}")?;
    }
    Ok(())
}

#[allow(
    clippy::disallowed_methods,
    reason = "a test tool at the edge, not the core: it reads the arm file it is given"
)]
fn load_arm(name: &str) -> Result<ArmDescription, Box<dyn Error>> {
    let is_toml = std::path::Path::new(name)
        .extension()
        .is_some_and(|extension| extension.eq_ignore_ascii_case("toml"));
    if is_toml {
        Ok(custom::parse_arm(&std::fs::read_to_string(name)?, name)?)
    } else {
        Ok(catalog::arm(name)?)
    }
}

fn evaluate<const N: usize>(
    arm: &ArmDescription,
    values: &[f64],
) -> Result<String, Box<dyn Error>> {
    let expected = 3 * N + 13;
    if values.len() != expected {
        return Err(format!("expected {expected} numbers, got {}", values.len()).into());
    }
    let array = |start: usize| -> [f64; N] { std::array::from_fn(|k| values[start + k]) };
    let (q, qd, qdd) = (array(0), array(N), array(2 * N));
    let rest = &values[3 * N..];
    let payload = Payload {
        mass_kg: rest[0],
        cog_flange_m: [rest[1], rest[2], rest[3]],
        inertia_cog_kg_m2: [rest[4], rest[5], rest[6], rest[7], rest[8], rest[9]],
    };
    let dynamics = ArmDynamics::<N>::from_arm(arm)?
        .with_payload(payload)?
        .with_gravity_base_m_s2([rest[10], rest[11], rest[12]])?;
    let mass = dynamics.mass_matrix_kg_m2(&q);
    let rows: Vec<String> = (0..N)
        .map(|i| list(&std::array::from_fn::<f64, N, _>(|j| mass[(i, j)])))
        .collect();
    let momentum = dynamics.momentum(&q, &qd);
    Ok(format!(
        "{{\"tau\":{},\"gravity\":{},\"coriolis\":{},\"mass_matrix\":[{}],\"momentum\":{},\"coriolis_transpose_qd\":{}}}",
        list(&dynamics.inverse_dynamics_nm(&q, &qd, &qdd)),
        list(&dynamics.gravity_nm(&q)),
        list(&dynamics.coriolis_nm(&q, &qd)),
        rows.join(","),
        list(&momentum.momentum_nms),
        list(&momentum.coriolis_transpose_qd_nm),
    ))
}

/// A JSON array of `values` in Rust's shortest round-trip form (`{:?}`: `1e-7`, `-0.0`).
fn list(values: &[f64]) -> String {
    let items: Vec<String> = values.iter().map(|v| format!("{v:?}")).collect();
    format!("[{}]", items.join(","))
}
