//! `armtwin config show`: the effective configuration, as `serve` would run it, printed as TOML.
//!
//! Owns the printing; must not merge or check anything (the library's `config` does).

use std::io::Write;

use anyhow::{Context, Result};
use armtwin_service::config::effective_toml;

use crate::flags::ConfigShowArgs;

pub(super) fn show(args: &ConfigShowArgs) -> Result<()> {
    let text = effective_toml(args.config.as_deref())?;
    let source = args.config.as_ref().map_or_else(
        || "the built-in default".to_owned(),
        |path| format!("{} over the built-in default", path.display()),
    );
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "# armtwin's effective configuration: {source}, every default filled in.\n\
         # Paths are relative to the configuration file; the command line's flags still apply."
    )
    .and_then(|()| out.write_all(text.as_bytes()))
    .context("cannot write to stdout")
}
