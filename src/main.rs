//! The `armtwin` binary: parses the command line and reports errors; all work is in the library.

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = armtwin::cli::Cli::parse();
    match armtwin::cli::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("armtwin: error: {error:#}");
            ExitCode::FAILURE
        }
    }
}
