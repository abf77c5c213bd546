//! The names `armtwin certs` writes (its source compiled here, without the certificates'
//! dependencies): a router name (`--router-name`) is an IP address or a lower-case ASCII DNS name
//! that reads back as itself; a fleet name taken as a file stem names one file in the output
//! folder, never a path out of it; every refusal names the input.

use std::path::{Component, Path};

use crate::certificate_names_file::{RESERVED_STEMS, RouterName, file_stem};

/// Runs every check of this parser on one input; panics on a broken invariant.
pub fn check(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    match text.parse::<RouterName>() {
        Ok(name) => {
            if let RouterName::Dns(dns) = &name {
                assert!(dns.len() <= 253, "{dns}");
                assert!(
                    dns.bytes().all(|b| b.is_ascii_lowercase()
                        || b.is_ascii_digit()
                        || b"-.".contains(&b)),
                    "{dns}"
                );
            }
            assert_eq!(name.to_string().parse::<RouterName>(), Ok(name));
        }
        Err(error) => assert!(error.to_string().contains(&format!("'{text}'")), "{error}"),
    }
    match file_stem(text) {
        Ok(stem) => {
            assert_eq!(stem, text);
            assert!(!RESERVED_STEMS.contains(&stem));
            for file in [format!("{stem}.pem"), format!("{stem}.key")] {
                let components: Vec<Component<'_>> = Path::new(&file).components().collect();
                assert!(
                    matches!(components[..], [Component::Normal(one)] if one == file.as_str()),
                    "{file:?} is not one file name"
                );
            }
        }
        Err(error) => assert!(
            error.to_string().contains("cannot name its files"),
            "{error}"
        ),
    }
}
