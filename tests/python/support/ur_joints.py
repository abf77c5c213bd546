"""The Universal Robots driver's joint names, for the ROS 2 tests and fixture writers (no
dependencies: also imported by the scripts that run in .venv-ros2)."""

# Base to flange, without the driver's tf_prefix.
UR_JOINTS = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]
# The order the UR driver's joint_state_broadcaster has been seen to publish (not the model's).
DRIVER_ORDER = [1, 2, 3, 4, 5, 0]
