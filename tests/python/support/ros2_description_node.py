"""A real ROS 2 node standing in for a non-UR arm's driver and its ``robot_state_publisher`` (run
in .venv-ros2, rclpy with Fast DDS): publishes the arm's URDF on ``robot_description``
(``std_msgs/String``, reliable, transient local, depth 1: as ``robot_state_publisher`` does) as
soon as it starts, then ``sensor_msgs/JointState`` on ``joint_states`` once a subscriber matches
and the test says go.

Prints one JSON line per milestone on stdout (``{"described": bytes}``, ``{"matched": …}``,
``{"published": n}``).

Usage: ros2_description_node.py --urdf panda.urdf --rows ROWS.json --namespace /panda --go GO_FILE
(ROWS.json: ``[{"sec", "nanosec", "names", "q"}, …]``; GO_FILE: publishing starts once it exists.)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

DESCRIPTION_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             history=HistoryPolicy.KEEP_LAST, depth=1)
JOINTS_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=1000)


def say(**fields) -> None:
    print(json.dumps(fields), flush=True)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--urdf", required=True)
    parser.add_argument("--rows", required=True)
    parser.add_argument("--namespace", required=True)
    parser.add_argument("--go", required=True)
    parser.add_argument("--rate-hz", type=float, default=100.0)
    parser.add_argument("--timeout", type=float, default=60.0)
    args = parser.parse_args()
    with open(args.rows) as f:
        rows = json.load(f)
    with open(args.urdf) as f:
        urdf = f.read()

    rclpy.init()
    node = Node("robot_state_publisher", namespace=args.namespace)
    description_pub = node.create_publisher(String, "robot_description", DESCRIPTION_QOS)
    joints_pub = node.create_publisher(JointState, "joint_states", JOINTS_QOS)
    description_pub.publish(String(data=urdf))
    say(described=len(urdf))

    def spin_until(predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                return False
            rclpy.spin_once(node, timeout_sec=0.05)
        return True

    matched = spin_until(lambda: joints_pub.get_subscription_count() > 0 and os.path.exists(args.go), args.timeout)
    say(matched=matched)
    if not matched:
        node.destroy_node()
        rclpy.shutdown()
        return 2
    period_s = 1.0 / args.rate_hz
    next_at = time.monotonic()
    for row in rows:
        msg = JointState()
        msg.header.stamp.sec = row["sec"]
        msg.header.stamp.nanosec = row["nanosec"]
        msg.name = row["names"]
        msg.position = row["q"]
        joints_pub.publish(msg)
        next_at += period_s
        while (left := next_at - time.monotonic()) > 0:
            rclpy.spin_once(node, timeout_sec=left)
    say(published=len(rows))
    # The description stays offered while the test reads the twin.
    spin_until(lambda: not os.path.exists(args.go), args.timeout)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
