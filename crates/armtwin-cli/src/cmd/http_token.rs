//! `armtwin http-token`: a new dashboard token on the first line of stdout, then the
//! configuration entry that holds its digest; what to do with each on stderr.
//!
//! Owns the output only; the token and its digest come from the library's `http_access`.

use std::io::{self, Write};

use anyhow::Result;
use armtwin_access::http_access::new_token;

use crate::flags::HttpTokenArgs;

pub(super) fn run(args: &HttpTokenArgs) -> Result<()> {
    let made = new_token()?;
    // JSON strings are TOML basic strings.
    let quoted = |text: &str| serde_json::to_string(text).unwrap_or_default();
    eprintln!(
        "The first line is the token of '{}' (role {}): give it to its client, it is shown only \
         here (Authorization: Bearer <token>; in a browser, user '{}' and the token as \
         password). The rest goes into [http] of armtwin's configuration.",
        args.name, args.role, args.name
    );
    let mut out = io::stdout().lock();
    writeln!(
        out,
        "{}\n\n[[http.tokens]]\nname = {}\nrole = {}\nhash = {}",
        made.token,
        quoted(&args.name),
        quoted(&args.role),
        quoted(&made.hash),
    )?;
    Ok(())
}
