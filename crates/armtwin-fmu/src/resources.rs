//! Where the FMU finds its robot: the `fmuResourceLocation` URI handed to `fmi2Instantiate`, and
//! the files in that folder (`armtwin-fmu.toml` and the calibration it names).
//!
//! URI parsing is pure; [`load`] is the library's only file access. The robot itself is built by
//! the core ([`FmuSettings::robot_model`]), exactly as `armtwin fmu build` validated it.

use std::path::{Path, PathBuf};

use armtwin_core::fmi::{FmuSettings, FmuSettingsError, RESOURCE_FILE};
use armtwin_core::model::RobotModel;
use thiserror::Error;

/// Why the FMU's resources cannot be used.
#[derive(Debug, Error)]
pub enum ResourceError {
    /// The location is not a `file:` URI with an absolute path.
    #[error("fmuResourceLocation '{uri}' is not a file URI (file:///path or file:/path)")]
    NotFileUri {
        /// The location given.
        uri: String,
    },
    /// The URI names a remote host.
    #[error(
        "fmuResourceLocation '{uri}' names host '{host}'; only local files (no host, or localhost) can be read"
    )]
    RemoteHost {
        /// The location given.
        uri: String,
        /// Its host.
        host: String,
    },
    /// A `%` is not followed by two hexadecimal digits.
    #[error("fmuResourceLocation '{uri}': '%' at byte {offset} is not followed by two hex digits")]
    PercentEncoding {
        /// The location given.
        uri: String,
        /// Byte offset of the `%` in the URI.
        offset: usize,
    },
    /// The decoded path is not valid on this platform.
    #[error("fmuResourceLocation '{uri}' does not decode to a valid path")]
    InvalidPath {
        /// The location given.
        uri: String,
    },
    /// A resource file cannot be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The robot description is invalid.
    #[error(transparent)]
    Settings(#[from] FmuSettingsError),
}

/// The folder named by `uri`, a `file:` URI (RFC 8089): `file:///abs/path`, `file:/abs/path` or
/// `file://localhost/abs/path`, percent-encoded; a query or fragment is ignored.
pub fn folder_from_uri(uri: &str) -> Result<PathBuf, ResourceError> {
    let not_file_uri = || ResourceError::NotFileUri {
        uri: uri.to_owned(),
    };
    let rest = uri
        .get(..5)
        .filter(|scheme| scheme.eq_ignore_ascii_case("file:"))
        .map(|_| &uri[5..])
        .ok_or_else(not_file_uri)?;
    let rest = rest.split(['?', '#']).next().unwrap_or_default();
    let path = match rest.strip_prefix("//") {
        Some(authority_and_path) => {
            let (host, path) = authority_and_path
                .find('/')
                .map_or((authority_and_path, ""), |slash| {
                    authority_and_path.split_at(slash)
                });
            if !(host.is_empty() || host.eq_ignore_ascii_case("localhost")) {
                return Err(ResourceError::RemoteHost {
                    uri: uri.to_owned(),
                    host: host.to_owned(),
                });
            }
            path
        }
        None => rest,
    };
    if !path.starts_with('/') {
        return Err(not_file_uri());
    }
    // `path` is a slice of `uri`: where it starts, for the error's offset.
    let offset_in_uri = path.as_ptr().addr() - uri.as_ptr().addr();
    let bytes = percent_decode(path).map_err(|offset| ResourceError::PercentEncoding {
        uri: uri.to_owned(),
        offset: offset_in_uri + offset,
    })?;
    path_from_bytes(bytes).ok_or_else(|| ResourceError::InvalidPath {
        uri: uri.to_owned(),
    })
}

/// Decodes `%XX` escapes; the error is the byte offset of a malformed escape.
fn percent_decode(text: &str) -> Result<Vec<u8>, usize> {
    let bytes = text.as_bytes();
    let mut decoded = Vec::with_capacity(bytes.len());
    let mut index = 0;
    while index < bytes.len() {
        if bytes[index] == b'%' {
            let hex = bytes
                .get(index + 1..index + 3)
                .and_then(|digits| std::str::from_utf8(digits).ok())
                .and_then(|digits| u8::from_str_radix(digits, 16).ok())
                .ok_or(index)?;
            decoded.push(hex);
            index += 3;
        } else {
            decoded.push(bytes[index]);
            index += 1;
        }
    }
    Ok(decoded)
}

#[cfg(unix)]
fn path_from_bytes(bytes: Vec<u8>) -> Option<PathBuf> {
    use std::os::unix::ffi::OsStringExt;
    (!bytes.contains(&0)).then(|| PathBuf::from(std::ffi::OsString::from_vec(bytes)))
}

#[cfg(not(unix))]
fn path_from_bytes(bytes: Vec<u8>) -> Option<PathBuf> {
    let text = String::from_utf8(bytes).ok()?;
    // `file:///C:/dir` carries the drive after the authority's slash.
    let text = match text.as_bytes() {
        [b'/', drive, b':', ..] if drive.is_ascii_alphabetic() => text[1..].to_owned(),
        _ => text,
    };
    (!text.contains('\0')).then(|| PathBuf::from(text))
}

/// The robot of an FMU: its settings and the model they build.
#[derive(Debug, Clone)]
pub struct Robot {
    /// The content of `armtwin-fmu.toml`.
    pub settings: FmuSettings,
    /// The model, with the settings' tool.
    pub model: RobotModel,
}

/// Reads `armtwin-fmu.toml` (and the calibration it names) from the resource `folder` and builds
/// the robot.
pub fn load(folder: &Path) -> Result<Robot, ResourceError> {
    let read = |name: &str| {
        let path = folder.join(name);
        std::fs::read_to_string(&path).map_err(|source| ResourceError::Read {
            path: path.display().to_string(),
            source,
        })
    };
    let settings = FmuSettings::from_toml(&read(RESOURCE_FILE)?)?;
    let calibration_text = settings.calibration_file.as_deref().map(read).transpose()?;
    let model = settings.robot_model(calibration_text.as_deref())?;
    Ok(Robot { settings, model })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn folder(uri: &str) -> PathBuf {
        folder_from_uri(uri).expect("valid file URI")
    }

    #[test]
    fn accepts_every_local_file_uri_form() {
        let expected = PathBuf::from("/tmp/fmu/resources");
        assert_eq!(folder("file:///tmp/fmu/resources"), expected);
        assert_eq!(folder("file:/tmp/fmu/resources"), expected);
        assert_eq!(folder("file://localhost/tmp/fmu/resources"), expected);
        assert_eq!(folder("FILE://LocalHost/tmp/fmu/resources"), expected);
        assert_eq!(
            folder("file:///tmp/fmu/resources/"),
            PathBuf::from("/tmp/fmu/resources/")
        );
        assert_eq!(folder("file:///tmp/fmu/resources?x=1#frag"), expected);
    }

    #[test]
    fn decodes_percent_escapes_to_bytes() {
        assert_eq!(
            folder("file:///tmp/my%20fmu/%23resources%25"),
            PathBuf::from("/tmp/my fmu/#resources%")
        );
        // UTF-8 bytes, escaped one by one (Python's pathlib as_uri does this).
        assert_eq!(
            folder("file:///tmp/Gr%C3%BC%C3%9Fe/resources"),
            PathBuf::from("/tmp/Grüße/resources")
        );
        assert_eq!(folder("file:///tmp/%7e%7E"), PathBuf::from("/tmp/~~"));
    }

    #[test]
    fn rejects_what_is_not_a_local_absolute_file_uri() {
        for uri in [
            "",
            "/tmp/fmu/resources",
            "http://host/x",
            "file:",
            "file:relative/path",
            "file://",
            "fil:///x",
        ] {
            assert!(
                matches!(folder_from_uri(uri), Err(ResourceError::NotFileUri { .. })),
                "{uri:?}"
            );
        }
        assert!(matches!(
            folder_from_uri("file://server/share/resources"),
            Err(ResourceError::RemoteHost { host, .. }) if host == "server"
        ));
        let error = folder_from_uri("file:///tmp/a%2/b").expect_err("bad escape");
        assert!(matches!(
            error,
            ResourceError::PercentEncoding { offset: 13, .. }
        ));
        assert!(matches!(
            folder_from_uri("file:///tmp/%zz"),
            Err(ResourceError::PercentEncoding { offset: 12, .. })
        ));
        assert!(matches!(
            folder_from_uri("file:///tmp/a%00b"),
            Err(ResourceError::InvalidPath { .. })
        ));
    }

    #[test]
    fn load_reads_settings_and_calibration_and_names_missing_files() {
        let dir = tempfile::tempdir().expect("temp dir");
        let error = load(dir.path()).expect_err("no settings file");
        assert!(error.to_string().contains("armtwin-fmu.toml"), "{error}");
        std::fs::write(
            dir.path().join(RESOURCE_FILE),
            "guid = \"{g}\"\nmodel = \"ur5e\"\ncalibration = \"cal.conf\"\nframe = \"base\"\n\
             tcp = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0]\n",
        )
        .expect("write");
        let error = load(dir.path()).expect_err("calibration missing");
        assert!(matches!(&error, ResourceError::Read { path, .. } if path.ends_with("cal.conf")));
        std::fs::write(
            dir.path().join("cal.conf"),
            "[mounting]\ndelta_theta = [0, 0, 0, 0, 0, 0]\ndelta_a = [0, 0, 0, 0, 0, 0]\n\
             delta_d = [0, 0, 0, 0, 0, 0]\ndelta_alpha = [0, 0, 0, 0, 0, 0]\n",
        )
        .expect("write");
        let robot = load(dir.path()).expect("valid resources");
        assert_eq!(robot.model.arm().name, "ur5e");
        assert!(robot.model.calibration().is_some());
        assert_eq!(robot.settings.guid, "{g}");
    }
}
