//! `armtwin-bench`: the service next to a plain-Zenoh echo under the same load (how to run it is
//! in this crate's README.md).
//!
//! - `run`: the orchestrator; starts the systems under test and the load generator as
//!   subprocesses and writes `bench.json`.
//! - `echo`: the plain-Zenoh echo, the baseline.
//! - `load`: the load generator.
//! - `soak`: hours under load with churn, Prometheus and a dashboard client; writes `soak.json`
//!   and `soak.svg`.
#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    reason = "the command line's own output and error reports"
)]

use armtwin_bench::{echo, load, run, soak};

use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// armtwin-bench: the service next to a plain Zenoh echo, side by side, over TCP loopback.
#[derive(Debug, Parser)]
#[command(name = "armtwin-bench", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run every benchmark and write bench.json.
    Run(run::RunArgs),
    /// The plain-Zenoh echo (a system under test).
    Echo(echo::EchoArgs),
    /// The load generator (prints its report as JSON).
    Load(load::LoadArgs),
    /// Hours under load with churn; writes soak.json and soak.svg.
    Soak(soak::SoakArgs),
}

fn execute(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run(args) => {
            run::run(&args)?;
        }
        Command::Echo(args) => echo::run(&args)?,
        Command::Soak(args) => {
            soak::run(&args)?;
        }
        Command::Load(args) => {
            let report = load::run(args)?;
            println!("{}", serde_json::to_string(&report)?);
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    match execute(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("armtwin-bench: error: {error:#}");
            ExitCode::FAILURE
        }
    }
}
