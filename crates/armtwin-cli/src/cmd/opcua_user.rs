//! `armtwin opcua-user`: the `[[opcua.users]]` entry of a user, its password read from stdin and
//! kept only as a salted digest.
//!
//! Owns the reading and the output; the digest comes from the OPC UA server's own `password`.

use std::io::{self, BufRead as _, Read as _, Write as _};

use anyhow::{Context, Result, bail};
use armtwin_opcua::PasswordHash;

use crate::flags::OpcuaUserArgs;

/// The longest password line read: a passphrase, not a file.
const MAX_PASSWORD_BYTES: u64 = 1024;

pub(super) fn run(args: &OpcuaUserArgs) -> Result<()> {
    if args.name.trim().is_empty() {
        bail!("a user name is needed");
    }
    let mut line = String::new();
    io::stdin()
        .lock()
        .take(MAX_PASSWORD_BYTES + 1)
        .read_line(&mut line)
        .context("cannot read the password from stdin")?;
    let password = line.strip_suffix('\n').unwrap_or(&line);
    let password = password.strip_suffix('\r').unwrap_or(password);
    if u64::try_from(line.len()).unwrap_or(u64::MAX) > MAX_PASSWORD_BYTES {
        bail!("the password is longer than {MAX_PASSWORD_BYTES} bytes");
    }
    if password.is_empty() {
        bail!(
            "no password on stdin: give it as one line (printf '%s\\n' \"$PASSWORD\" | armtwin opcua-user NAME)"
        );
    }
    let digest = PasswordHash::of(password).context("the system's random source failed")?;
    // JSON strings are TOML basic strings.
    let quoted = |text: &str| serde_json::to_string(text).unwrap_or_default();
    eprintln!(
        "The entry of '{}' for [opcua] of armtwin's configuration: it signs in with that \
         password on the encrypted endpoints. The password itself is kept nowhere.",
        args.name
    );
    writeln!(
        io::stdout().lock(),
        "[[opcua.users]]\nname = {}\npassword_hash = {}",
        quoted(&args.name),
        quoted(&digest.to_stored())
    )?;
    Ok(())
}
