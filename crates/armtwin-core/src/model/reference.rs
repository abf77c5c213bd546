//! How a configuration or a command line names a robot's arm: a catalog name (`ur10e`), the
//! path of a custom arm's TOML file (`arm.toml`) or of a URDF description (`robot.urdf`).
//!
//! Owns that one rule. Must not open the file: the caller reads it and hands the text to
//! [`custom::parse_arm`](super::custom::parse_arm).

use std::path::Path;

/// An arm as a user names it.
///
/// ```
/// use std::path::Path;
/// use armtwin_core::model::ModelRef;
/// assert_eq!(ModelRef::parse("ur10e"), ModelRef::Catalog("ur10e"));
/// assert_eq!(
///     ModelRef::parse("arms/my_arm.toml"),
///     ModelRef::CustomArm(Path::new("arms/my_arm.toml"))
/// );
/// assert_eq!(ModelRef::parse("panda.urdf"), ModelRef::Urdf(Path::new("panda.urdf")));
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelRef<'a> {
    /// A name from [`catalog`](super::catalog).
    Catalog(&'a str),
    /// The path of a custom arm's TOML description (relative to whatever the caller resolves
    /// paths against).
    CustomArm(&'a Path),
    /// The path of a URDF description ([`urdf`](super::urdf)).
    Urdf(&'a Path),
}

impl<'a> ModelRef<'a> {
    /// What `name` refers to: a path ending in `.toml` is a custom arm, one ending in `.urdf` a
    /// URDF, anything else a catalog name (an unknown one is refused by the catalog, with the
    /// names it has).
    #[must_use]
    pub fn parse(name: &'a str) -> Self {
        let path = Path::new(name);
        match path.extension().and_then(|e| e.to_str()) {
            Some("toml") => Self::CustomArm(path),
            Some("urdf") => Self::Urdf(path),
            _ => Self::Catalog(name),
        }
    }
}
