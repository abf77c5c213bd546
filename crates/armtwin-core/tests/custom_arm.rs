//! Custom arms from TOML: standard and modified DH tables of one arm agree with the catalog.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use armtwin_core::kinematics::{OutputFrame, TcpOffset};
use armtwin_core::model::{RobotModel, custom};

const UR10E_STANDARD_DEG: &str = r#"
name = "ur10e-by-hand"
convention = "standard"
angle_unit = "deg"
[[joints]]
a = 0.0
alpha = 90
d = 0.1807
min = -360
max = 360
[[joints]]
a = -0.6127
alpha = 0
d = 0
[[joints]]
a = -0.57155
alpha = 0
d = 0
[[joints]]
a = 0
alpha = 90
d = 0.17415
[[joints]]
a = 0
alpha = -90
d = 0.11985
[[joints]]
a = 0
alpha = 0
d = 0.11655
"#;

/// The `ur10e` in Craig's convention: row i holds `(a(i-1), alpha(i-1), d(i))`.
const UR10E_MODIFIED: &str = r#"
name = "ur10e-craig"
convention = "modified"
[[joints]]
a = 0.0
alpha = 0.0
d = 0.1807
[[joints]]
a = 0.0
alpha = 1.5707963267948966
d = 0.0
[[joints]]
a = -0.6127
alpha = 0.0
d = 0.0
[[joints]]
a = -0.57155
alpha = 0.0
d = 0.17415
[[joints]]
a = 0.0
alpha = 1.5707963267948966
d = 0.11985
[[joints]]
a = 0.0
alpha = -1.5707963267948966
d = 0.11655
"#;

fn model(text: &str) -> RobotModel {
    let arm = custom::parse_arm(text, "arm.toml").expect("valid arm");
    RobotModel::new(arm, None, TcpOffset::FLANGE, OutputFrame::Base).expect("model")
}

#[test]
fn standard_and_modified_tables_match_the_catalog() {
    let catalog = RobotModel::nominal("ur10e").expect("catalog");
    let standard = model(UR10E_STANDARD_DEG);
    let modified = model(UR10E_MODIFIED);
    assert_eq!(
        standard.arm().joint_limits[0].max_rad,
        Some(std::f64::consts::TAU)
    );
    assert_eq!(standard.arm().joint_limits[1].max_rad, None);
    for q in [
        [0.0; 6],
        [0.3, -1.2, 1.1, -0.4, 1.57, 2.9],
        [-2.0, -0.5, 2.5, 1.0, -1.0, -3.0],
    ] {
        let expected = catalog.pose(&q).expect("valid");
        for other in [&standard, &modified] {
            let pose = other.pose(&q).expect("valid");
            assert!((pose.position_m - expected.position_m).norm() < 1e-14);
            assert!((pose.rotation - expected.rotation).norm() < 1e-14);
        }
    }
}

#[test]
fn any_number_of_joints() {
    let planar = model(
        "name = \"planar-3r\"\nconvention = \"standard\"\n[[joints]]\na = 1\nalpha = 0\nd = 0\n[[joints]]\na = 1\nalpha = 0\nd = 0\n[[joints]]\na = 0.5\nalpha = 0\nd = 0\n",
    );
    assert_eq!(planar.joint_count(), 3);
    let pose = planar
        .pose(&[std::f64::consts::FRAC_PI_2, 0.0, 0.0])
        .expect("valid");
    assert!((pose.position_m.y - 2.5).abs() < 1e-15 && pose.position_m.x.abs() < 1e-15);
}

#[test]
fn invalid_files_say_what_and_where() {
    let error = |text: &str| {
        custom::parse_arm(text, "bad.toml")
            .expect_err("invalid")
            .to_string()
    };
    assert!(
        error("name = \"x\"\nconvention = \"standard\"\njoints = []\n")
            .contains("at least one joint")
    );
    let typo = error(
        "name = \"x\"\nconvention = \"standard\"\n[[joints]]\na = 0\nalpha = 0\nd = 0\nlenght = 1\n",
    );
    assert!(
        typo.starts_with("bad.toml") && typo.contains("lenght"),
        "{typo}"
    );
    let convention =
        error("name = \"x\"\nconvention = \"craig\"\n[[joints]]\na = 0\nalpha = 0\nd = 0\n");
    assert!(convention.contains("craig"), "{convention}");
    let limits = error(
        "name = \"x\"\nconvention = \"standard\"\n[[joints]]\na = 0\nalpha = 0\nd = 0\nmin = 1\nmax = -1\n",
    );
    assert!(
        limits.contains("joints[1]: min 1 is above max -1"),
        "{limits}"
    );
    let infinite =
        error("name = \"x\"\nconvention = \"standard\"\n[[joints]]\na = inf\nalpha = 0\nd = 0\n");
    assert!(
        infinite.contains("joints[1].a: inf is not finite"),
        "{infinite}"
    );
}
