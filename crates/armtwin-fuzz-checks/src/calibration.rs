//! A robot's factory calibration as operators hand it in (`calibration.conf`, `ur_calibration`
//! YAML): `[mounting]` deltas written back as `calibration.conf` must parse to the same deltas;
//! anything else is an error naming the file, never a panic.

use armtwin_core::model::{Calibration, CalibrationForm};

const SOURCE: &str = "fuzz/calibration";

/// Runs every check of this decoder on one input; panics on a broken invariant.
pub fn check(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    for parsed in [
        Calibration::parse(text, SOURCE),
        Calibration::parse_conf(text, SOURCE),
        Calibration::parse_yaml(text, SOURCE),
    ] {
        let calibration = match parsed {
            Ok(calibration) => calibration,
            Err(error) => {
                assert!(error.to_string().contains(SOURCE), "{error}");
                continue;
            }
        };
        assert_eq!(calibration.source_name, SOURCE);
        match &calibration.form {
            CalibrationForm::MountingDeltas(deltas) => {
                let text = deltas.to_conf_text("written back");
                let again = Calibration::parse_conf(&text, SOURCE).expect("written deltas");
                assert_eq!(again, calibration);
            }
            CalibrationForm::JointOrigins {
                parent_from_joint, ..
            } => {
                assert_eq!(parent_from_joint.len(), 6);
                for origin in parent_from_joint {
                    let matrix = origin.to_homogeneous();
                    assert!(matrix.iter().all(|v| v.is_finite()), "{matrix}");
                }
            }
        }
    }
}
