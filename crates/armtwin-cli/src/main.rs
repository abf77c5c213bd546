//! The `armtwin` binary: parses the command line, sets up logging and reports errors; the
//! commands are in this crate's library, all computing in the `armtwin` library.
#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    reason = "the command line's own output and error reports"
)]

use std::io::IsTerminal;
use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = armtwin_cli::flags::Cli::parse();
    // Logs go to stderr, so `fk --csv` output on stdout stays clean; RUST_LOG overrides.
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("armtwin=info,zenoh=warn")),
        )
        .init();
    match armtwin_cli::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            if let Some(gate) = error.downcast_ref::<armtwin_cli::GateFailed>() {
                eprintln!("armtwin: gate failed: {gate}");
                return ExitCode::from(armtwin_cli::EXIT_GATE_FAILED);
            }
            eprintln!("armtwin: error: {error:#}");
            ExitCode::FAILURE
        }
    }
}
