//! `armtwin ik`: every joint configuration reaching a TCP pose, as JSON.
//!
//! Owns reading the request from the flags and writing the answer; must not solve (the library's
//! `ik` does).

use std::io::{self, Write};

use anyhow::{Context, Result};
use armtwin_codec::ik::{IkAnswerJson, IkRequest};

use crate::flags::IkArgs;

pub(super) fn run(args: &IkArgs) -> Result<()> {
    let model = args.robot.load()?;
    let request = IkRequest::new(&args.pose, args.seed.clone()).context("--pose")?;
    let answer = armtwin_core::ik::solve(&model, &request.target, request.seed())?;
    let output = IkAnswerJson::from(&answer);
    let stdout = io::stdout();
    let mut out = stdout.lock();
    serde_json::to_writer(&mut out, &output)?;
    writeln!(out)?;
    Ok(())
}
