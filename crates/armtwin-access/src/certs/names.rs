//! The names `armtwin certs` writes into certificates and files: the router's host names (a DNS
//! name or an IP address each, `--router-name`) and a fleet name as the stem of its files.
//!
//! Pure and std-only, so that the fuzz checks compile it from this source: must not know
//! certificates, keys or the file system.

use std::fmt;
use std::net::IpAddr;
use std::str::FromStr;

use thiserror::Error;

/// The longest DNS name (RFC 1035: 255 octets on the wire, 253 characters written).
const MAX_DNS_NAME: usize = 253;
/// The longest DNS label.
const MAX_LABEL: usize = 63;
/// The longest fleet name written as a file stem (`<name>.pem`, `<name>.key` stay under 255
/// bytes, what Linux file systems take).
const MAX_FILE_STEM: usize = 200;
/// The files' stems of the CA and the router: no fleet name may take them.
pub const RESERVED_STEMS: [&str; 2] = ["ca", "router"];

/// A name clients reach the router by, written into its certificate's subject alternative
/// names: what `verify_name_on_connect` checks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RouterName {
    /// A DNS name, lower-cased (`localhost`, `router.plant`).
    Dns(String),
    /// An IP address (`127.0.0.1`, `::1`).
    Ip(IpAddr),
}

/// Why a name cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum NameError {
    /// `--router-name` is neither an IP address nor a DNS name.
    #[error(
        "router name '{name}' is neither an IP address nor a DNS name: {problem} (letters, digits \
         and '-' in dot-separated labels of 1 to 63, 253 characters at most, no wildcard)"
    )]
    RouterName {
        /// The name given.
        name: String,
        /// What is wrong with it.
        problem: &'static str,
    },
    /// A fleet name that cannot be the stem of its files.
    #[error("fleet name '{name}' cannot name its files <name>.pem and <name>.key: {problem}")]
    FileStem {
        /// The name given.
        name: String,
        /// What is wrong with it.
        problem: &'static str,
    },
}

impl FromStr for RouterName {
    type Err = NameError;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        if let Ok(ip) = name.parse::<IpAddr>() {
            return Ok(Self::Ip(ip));
        }
        let refused = |problem| NameError::RouterName {
            name: name.to_owned(),
            problem,
        };
        if name.is_empty() {
            return Err(refused("it is empty"));
        }
        if name.len() > MAX_DNS_NAME {
            return Err(refused("it is too long"));
        }
        for label in name.split('.') {
            if label.is_empty() {
                return Err(refused("it has an empty label"));
            }
            if label.len() > MAX_LABEL {
                return Err(refused("a label is too long"));
            }
            if !label
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'-')
            {
                return Err(refused("a label holds another character"));
            }
            if label.starts_with('-') || label.ends_with('-') {
                return Err(refused("a label starts or ends with '-'"));
            }
        }
        if name
            .rsplit('.')
            .next()
            .is_some_and(|top| top.bytes().all(|b| b.is_ascii_digit()))
        {
            // `10.0.0.300` or `1.2.3`: a mistyped address, which no resolver takes as a name.
            return Err(refused("its last label is all digits"));
        }
        Ok(Self::Dns(name.to_ascii_lowercase()))
    }
}

impl fmt::Display for RouterName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Dns(name) => f.write_str(name),
            Self::Ip(ip) => ip.fmt(f),
        }
    }
}

/// `name` if it can be the stem of its certificate's and key's files in the output folder: one
/// file name, not hidden, no control character, not the CA's or the router's.
pub fn file_stem(name: &str) -> Result<&str, NameError> {
    let refused = |problem| NameError::FileStem {
        name: name.to_owned(),
        problem,
    };
    if name.is_empty() {
        return Err(refused("it is empty"));
    }
    if name.len() > MAX_FILE_STEM {
        return Err(refused("it is too long"));
    }
    if name.contains(['/', '\\']) {
        return Err(refused("it holds a path separator"));
    }
    if name.starts_with('.') {
        return Err(refused("it starts with '.'"));
    }
    if name.chars().any(char::is_control) {
        return Err(refused("it holds a control character"));
    }
    if RESERVED_STEMS.contains(&name) {
        return Err(refused("the CA's and the router's files take that name"));
    }
    Ok(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn router_names_are_addresses_or_dns_names() {
        assert_eq!(
            "127.0.0.1".parse::<RouterName>(),
            Ok(RouterName::Ip("127.0.0.1".parse().expect("an address")))
        );
        assert_eq!(
            "::1".parse::<RouterName>(),
            Ok(RouterName::Ip("::1".parse().expect("an address")))
        );
        assert_eq!(
            "Router.Plant".parse::<RouterName>(),
            Ok(RouterName::Dns("router.plant".to_owned()))
        );
        for bad in [
            "",
            "*.plant",
            "a..b",
            "-a",
            "a-",
            "a b",
            "10.0.0.300",
            "é.plant",
            "a.",
            ".a",
        ] {
            let error = bad.parse::<RouterName>().expect_err(bad).to_string();
            assert!(error.contains(&format!("'{bad}'")), "{error}");
        }
        let long = vec!["a".repeat(63); 4].join(".");
        assert!(
            long.parse::<RouterName>().is_err(),
            "{} characters",
            long.len()
        );
    }

    #[test]
    fn fleet_names_are_single_file_stems_but_the_reserved_ones() {
        assert_eq!(file_stem("g1"), Ok("g1"));
        assert_eq!(file_stem("cell-a"), Ok("cell-a"));
        for bad in ["", "../g1", "a/b", ".hidden", "ca", "router", "a\nb"] {
            let error = file_stem(bad).expect_err(bad).to_string();
            assert!(error.contains("cannot name its files"), "{error}");
        }
    }
}
