//! What a gateway learns of a controller beyond its samples, as one message on
//! `<prefix>/controller/<robot>` (docs/protocol/sources.md, *Controller facts*): the TCP its
//! measured poses are of (RTDE `tcp_offset`), its software version, its model and serial number
//! (its dashboard server), and why the dashboard server could not be read, if it could not. The
//! gateway writes it, the service reads it: both through here.
//!
//! Owns the message's JSON and its bounds (every text in it came from a controller, through a
//! gateway: untrusted), and what a dashboard server's model answer names in the catalog. Must not
//! open a socket or know Zenoh.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Longest facts message taken, in bytes.
pub const MAX_MESSAGE_BYTES: usize = 4096;
/// Longest model or serial number kept, in characters: UR's are a dozen.
pub const MAX_TEXT_CHARS: usize = 64;
/// Longest error text kept, in characters.
pub const MAX_ERROR_CHARS: usize = 256;

/// A controller's facts, each absent until read.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerFacts {
    /// The controller's software version: major, minor, bugfix, build (3 for CB3, 5 for
    /// e-Series).
    #[serde(default)]
    pub version: Option<[u32; 4]>,
    /// The TCP in the tool flange frame: `x, y, z` (m) and a rotation vector (rad), as RTDE's
    /// `tcp_offset` gives it.
    #[serde(default)]
    pub tcp_offset: Option<[f64; 6]>,
    /// The dashboard server's answer to `get robot model` (`UR10`: the family, without the
    /// e-Series' `e`).
    #[serde(default)]
    pub model: Option<String>,
    /// The dashboard server's answer to `get serial number`.
    #[serde(default)]
    pub serial: Option<String>,
    /// Why the dashboard server could not be read, if it could not.
    #[serde(default)]
    pub dashboard_error: Option<String>,
}

/// Why a facts message is refused.
#[derive(Debug, Error)]
pub enum FactsError {
    /// Over [`MAX_MESSAGE_BYTES`].
    #[error("{bytes} bytes, over the {MAX_MESSAGE_BYTES} a controller facts message may have")]
    TooLarge {
        /// Its size.
        bytes: usize,
    },
    /// Not the message's JSON.
    #[error("not a controller facts message: {0}")]
    Json(#[from] serde_json::Error),
    /// A `tcp_offset` value that is not finite.
    #[error("tcp_offset holds a value that is not finite")]
    NonFinite,
}

/// `text` as shown and logged: control characters dropped, cut at `max_chars`.
#[must_use]
pub fn clean_text(text: &str, max_chars: usize) -> String {
    text.trim()
        .chars()
        .filter(|c| !c.is_control())
        .take(max_chars)
        .collect()
}

impl ControllerFacts {
    /// The message's JSON.
    #[must_use]
    pub fn to_json(&self) -> Vec<u8> {
        // A struct of numbers, strings and options always serialises.
        serde_json::to_vec(self).unwrap_or_default()
    }

    /// A message read back, its texts cleaned and bounded.
    pub fn from_json(payload: &[u8]) -> Result<Self, FactsError> {
        if payload.len() > MAX_MESSAGE_BYTES {
            return Err(FactsError::TooLarge {
                bytes: payload.len(),
            });
        }
        let mut facts: Self = serde_json::from_slice(payload)?;
        if facts
            .tcp_offset
            .is_some_and(|tcp| tcp.iter().any(|v| !v.is_finite()))
        {
            return Err(FactsError::NonFinite);
        }
        let clean = |text: &mut Option<String>, max_chars| {
            *text = text
                .take()
                .map(|t| clean_text(&t, max_chars))
                .filter(|t| !t.is_empty());
        };
        clean(&mut facts.model, MAX_TEXT_CHARS);
        clean(&mut facts.serial, MAX_TEXT_CHARS);
        clean(&mut facts.dashboard_error, MAX_ERROR_CHARS);
        Ok(facts)
    }

    /// The catalog name of the controller's arm (`ur10e`), from the dashboard's model and the
    /// controller's major version: the dashboard names the family (`UR10`) for a CB3 (major 3)
    /// and an e-Series (5) alike. `None` when the model is unknown or not a UR name, or names a
    /// family built as both while the version is unknown.
    #[must_use]
    pub fn catalog_model(&self) -> Option<String> {
        let family = self.model.as_deref()?.to_ascii_lowercase();
        let digits = family.strip_prefix("ur")?;
        let (number, e_series) = match digits.strip_suffix('e') {
            Some(number) => (number, true),
            None => (digits, false),
        };
        if number.is_empty() || !number.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        // Only the UR3, UR5, UR10 and UR16 were built as both; later arms have no suffix.
        let both_series = matches!(number, "3" | "5" | "10" | "16");
        if !both_series {
            return Some(format!("ur{number}"));
        }
        let major = self.version.map(|[major, ..]| major);
        match (e_series, major) {
            (true, _) => Some(format!("ur{number}e")),
            (false, Some(major)) if major >= 5 => Some(format!("ur{number}e")),
            (false, Some(_)) => Some(format!("ur{number}")),
            (false, None) => None,
        }
    }

    /// Whether the controller's arm is `configured` (a model name of the configuration):
    /// `None` when either is not a UR catalog name, or the controller's model is unknown.
    #[must_use]
    pub fn model_agrees(&self, configured: &str) -> Option<bool> {
        let configured = configured.to_ascii_lowercase();
        let is_ur = configured.strip_prefix("ur").is_some_and(|rest| {
            rest.trim_end_matches('e')
                .bytes()
                .all(|b| b.is_ascii_digit())
        });
        if !is_ur {
            return None;
        }
        self.catalog_model().map(|model| model == configured)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn facts(model: &str, major: u32) -> ControllerFacts {
        ControllerFacts {
            version: Some([major, 21, 0, 9]),
            model: Some(model.to_owned()),
            ..ControllerFacts::default()
        }
    }

    #[test]
    fn the_dashboard_family_and_the_major_version_name_the_arm() {
        assert_eq!(facts("UR10", 5).catalog_model().as_deref(), Some("ur10e"));
        assert_eq!(facts("UR10", 3).catalog_model().as_deref(), Some("ur10"));
        assert_eq!(facts("UR20", 5).catalog_model().as_deref(), Some("ur20"));
        assert_eq!(facts("UR5e", 3).catalog_model().as_deref(), Some("ur5e"));
        assert_eq!(facts("Could not understand", 5).catalog_model(), None);
        assert_eq!(facts("UR", 5).catalog_model(), None);
        let unversioned = |model: &str| ControllerFacts {
            version: None,
            ..facts(model, 5)
        };
        assert_eq!(unversioned("UR10").catalog_model(), None);
        assert_eq!(unversioned("UR30").catalog_model().as_deref(), Some("ur30"));
        assert_eq!(facts("UR10", 5).model_agrees("ur10e"), Some(true));
        assert_eq!(facts("UR5", 5).model_agrees("UR10e"), Some(false));
        assert_eq!(facts("UR10", 5).model_agrees("arms/my-arm.toml"), None);
        assert_eq!(ControllerFacts::default().model_agrees("ur10e"), None);
    }

    #[test]
    fn a_message_reads_back_with_its_texts_bounded() {
        let sent = ControllerFacts {
            version: Some([5, 21, 0, 9]),
            tcp_offset: Some([0.0, 0.0, 0.2, 0.0, 0.0, 1.5]),
            model: Some("UR10".to_owned()),
            serial: Some("20235500001".to_owned()),
            dashboard_error: None,
        };
        assert_eq!(ControllerFacts::from_json(&sent.to_json()).unwrap(), sent);
        let long = format!(r#"{{"serial": "1\u0007{}"}}"#, "2".repeat(500));
        let read = ControllerFacts::from_json(long.as_bytes()).unwrap();
        assert_eq!(read.serial.unwrap(), format!("1{}", "2".repeat(63)));
        assert!(ControllerFacts::from_json(br#"{"tcp_offset": [0, 0, 0, 0, 0]}"#).is_err());
        assert!(ControllerFacts::from_json(br#"{"serial": 5}"#).is_err());
        assert!(ControllerFacts::from_json(&vec![b' '; MAX_MESSAGE_BYTES + 1]).is_err());
    }
}
