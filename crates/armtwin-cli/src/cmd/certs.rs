//! `armtwin certs`: the fleet description read from its file, its certificates written into a
//! folder, each key readable by its owner only.
//!
//! Owns the files; must not build a certificate (the library's `certs` does) nor parse the fleet
//! description (`acl` does).

use std::fs::OpenOptions;
use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use armtwin_access::acl::Fleet;
use armtwin_access::certs::{self, names::RouterName};

use super::read_text;
use crate::flags::CertsArgs;

/// A private key's mode: its owner reads and writes it, nobody else.
const KEY_MODE: u32 = 0o600;
/// A certificate's mode: public.
const CERTIFICATE_MODE: u32 = 0o644;

pub(super) fn run(args: &CertsArgs) -> Result<()> {
    let fleet = Fleet::parse(&read_text(&args.fleet)?)
        .with_context(|| format!("{} is not a fleet description", args.fleet.display()))?;
    let router_names = if args.router_names.is_empty() {
        vec![
            RouterName::Dns("localhost".to_owned()),
            RouterName::Ip(std::net::Ipv4Addr::LOCALHOST.into()),
        ]
    } else {
        args.router_names.clone()
    };
    let issued = certs::issue(&fleet, &router_names, args.days)?;
    let files: Vec<(PathBuf, &str, u32)> = issued
        .iter()
        .flat_map(|one| {
            [
                (
                    args.dir.join(format!("{}.pem", one.stem)),
                    one.certificate_pem.as_str(),
                    CERTIFICATE_MODE,
                ),
                (
                    args.dir.join(format!("{}.key", one.stem)),
                    one.private_key_pem.as_str(),
                    KEY_MODE,
                ),
            ]
        })
        .collect();
    // All or nothing: a half-written set would mix two CAs.
    let existing: Vec<String> = files
        .iter()
        .filter(|(path, ..)| path.symlink_metadata().is_ok())
        .map(|(path, ..)| path.display().to_string())
        .collect();
    if !existing.is_empty() && !args.force {
        bail!(
            "{} already exist: nothing written (--force replaces them)",
            existing.join(", ")
        );
    }
    std::fs::create_dir_all(&args.dir)
        .with_context(|| format!("cannot make {}", args.dir.display()))?;
    for (path, text, mode) in &files {
        write_file(path, text, *mode)?;
    }
    let router: Vec<String> = router_names.iter().map(ToString::to_string).collect();
    eprintln!(
        "{}: the CA, the router ({}) and {} client certificates ({}), valid {} days",
        args.dir.display(),
        router.join(", "),
        issued.len() - 2,
        issued[2..]
            .iter()
            .map(|one| one.stem.as_str())
            .collect::<Vec<_>>()
            .join(", "),
        args.days
    );
    Ok(())
}

/// Writes `text` to `path` with `mode`, whatever the file had: an existing file is removed first,
/// so that a key never lands in a file that others could already read.
fn write_file(path: &Path, text: &str, mode: u32) -> Result<()> {
    match std::fs::remove_file(path) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(e).with_context(|| format!("cannot replace {}", path.display())),
    }
    OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode)
        .open(path)
        .and_then(|mut file| file.write_all(text.as_bytes()))
        .with_context(|| format!("cannot write {}", path.display()))
}
