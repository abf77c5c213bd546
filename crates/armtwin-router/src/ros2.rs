//! Whether the ROS 2 DDS bridge may run in this router.
//!
//! The bridge is a plugin of the router's own runtime: what it puts on the mesh for any DDS
//! participant enters as the router itself, past the access control, which judges sessions on
//! links only (`tests/python/test_ros2_real.py` shows a ROS 2 publisher's joints passing rules
//! that drop a Zenoh client's). So, as REST inside the router, the bridge runs beside access control
//! only when the operator says the DDS domain is trusted (`--ros2-trusted`). Must not start or
//! configure the bridge.

use anyhow::{Result, bail};

/// Checks the bridge against the router's access control: `Ok(true)` when it runs past an
/// access control it was trusted to bypass (the start log says so), `Ok(false)` when it runs
/// with nothing to bypass or does not run.
pub fn bridge_allowed(bridge: bool, access_control: bool, trusted: bool) -> Result<bool> {
    match (bridge, access_control, trusted) {
        (false, _, true) => bail!(
            "--ros2-trusted without the ROS 2 bridge: add --ros2dds or a plugins/ros2dds section"
        ),
        (true, true, false) => bail!(
            "the router has access control, which the ROS 2 bridge bypasses: the bridge runs in \
             the router's own session, so every DDS participant of its domain may put any key \
             (another robot's joints, twin/admin/**) as the router itself. Run the bridge in a \
             router without access control, or pass --ros2-trusted if every participant of the \
             DDS domain is trusted"
        ),
        (true, true, true) => Ok(true),
        _ => Ok(false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bridge_runs_beside_access_control_only_when_trusted() {
        assert!(!bridge_allowed(true, false, false).expect("no access control"));
        assert!(!bridge_allowed(false, true, false).expect("no bridge"));
        assert!(bridge_allowed(true, true, true).expect("trusted"));
        let refused = bridge_allowed(true, true, false).expect_err("untrusted");
        assert!(refused.to_string().contains("--ros2-trusted"), "{refused}");
        let pointless = bridge_allowed(false, false, true).expect_err("no bridge to trust");
        assert!(pointless.to_string().contains("--ros2dds"), "{pointless}");
    }
}
