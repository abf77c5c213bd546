//! `armtwin acl`: a fleet description read from its file, its access control printed or written
//! into a router configuration.
//!
//! Owns the files and the output; must not build a rule (the library's `acl` does).

use std::io::{self, Write};

use anyhow::{Context, Result};
use armtwin_access::acl::{self, Fleet};

use super::read_text;
use crate::flags::AclArgs;

pub(super) fn run(args: &AclArgs) -> Result<()> {
    let fleet = Fleet::parse(&read_text(&args.fleet)?)
        .with_context(|| format!("{} is not a fleet description", args.fleet.display()))?;
    let section = fleet.access_control();
    let Some(router_config) = &args.update else {
        let mut out = io::stdout().lock();
        writeln!(out, "{}", acl::to_json5_text(&section))?;
        return Ok(());
    };
    let text = read_text(router_config)?;
    let updated = acl::replace_section(&text, &section).with_context(|| {
        format!(
            "{} has no '{}' line followed by an '{}' line to write between",
            router_config.display(),
            acl::BEGIN_MARK,
            acl::END_MARK
        )
    })?;
    if updated == text {
        eprintln!("{}: already up to date", router_config.display());
        return Ok(());
    }
    std::fs::write(router_config, updated)
        .with_context(|| format!("cannot write {}", router_config.display()))?;
    eprintln!(
        "{}: access_control written for {} names",
        router_config.display(),
        fleet.names().len()
    );
    Ok(())
}
