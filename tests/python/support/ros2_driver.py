"""A real ROS 2 node standing in for the Universal Robots driver (run in .venv-ros2, rclpy with
Fast DDS): publishes ``sensor_msgs/JointState`` on ``joint_states`` and ``geometry_msgs/PoseStamped``
on ``tcp_pose_broadcaster/pose`` in its namespace, from rows a test writes to a JSON file, and
subscribes ``armtwin/tcp_pose``, the twin's pose coming back through the bridge.

JointState as the driver writes it: joint names with the ``tf_prefix`` in a shuffled order, a
gripper joint in every third message, velocity and effort per name; the pose in
``<tf_prefix>base``. QoS: reliable, keep-last 1000 (the driver's broadcasters keep 10; the deeper
history only lets a loaded test machine catch up instead of overwriting samples).

Prints one JSON line per milestone on stdout (``{"matched": …}``, ``{"published": n}``) and, at the
end, writes ``--out``: the twin poses received (decoded by rclpy), the type hashes rclpy reports
for both published topics, and the bytes of one message of each kind as rclpy serializes it.

Usage: ros2_driver.py --rows ROWS.json --namespace /ur5 --tf-prefix ur5_ --rate-hz 250 --out OUT.json
(``--csv tests/data/ur10e_lasttest.csv --count N`` instead of ``--rows``: the recording's first N rows
restamped at 500 Hz, velocities from the angles, no effort; for running it by hand.)
"""

from __future__ import annotations

import argparse
import csv
import json
import random
import sys
import time

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from ur_joints import UR_JOINTS  # run by path: its own directory is on sys.path

QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=1000)


def say(**fields) -> None:
    print(json.dumps(fields), flush=True)


def joint_state(row: dict, tf_prefix: str, rng: random.Random) -> JointState:
    efforts = row["effort"] or [None] * len(UR_JOINTS)
    entries = [
        (f"{tf_prefix}{name}", q, qd, effort)
        for name, q, qd, effort in zip(UR_JOINTS, row["q"], row["qd"], efforts)
    ]
    if rng.random() < 1 / 3:
        entries.append((f"{tf_prefix}gripper_joint", 0.02, 0.0, 0.4))
    rng.shuffle(entries)
    msg = JointState()
    msg.header.stamp.sec = row["sec"]
    msg.header.stamp.nanosec = row["nanosec"]
    msg.name = [name for name, _, _, _ in entries]
    msg.position = [q for _, q, _, _ in entries]
    msg.velocity = [qd for _, _, qd, _ in entries]
    msg.effort = [effort for _, _, _, effort in entries] if row["effort"] else []
    return msg


def pose_stamped(row: dict, frame_id: str) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp.sec = row["sec"]
    msg.header.stamp.nanosec = row["nanosec"]
    msg.header.frame_id = frame_id
    x, y, z, qx, qy, qz, qw = row["pose"]
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = qx, qy, qz, qw
    return msg


def rows_from_csv(path: str, count: int) -> list[dict]:
    """The first ``count`` rows of a recording in the UR10e report's CSV form (time, 6 angles,
    x y z qx qy qz qw), stamped at 500 Hz from now, velocities by differences of the angles."""
    rate_hz = 500
    start_ns = time.time_ns()
    rows: list[dict] = []
    with open(path, newline="") as f:
        reader = csv.reader(f)
        next(reader)
        for i, record in zip(range(count), reader):
            values = [float(v) for v in record[1:14]]
            ns = start_ns + i * (1_000_000_000 // rate_hz)
            q = values[:6]
            previous = rows[-1]["q"] if rows else q
            rows.append({"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000, "q": q,
                         "qd": [(a - b) * rate_hz for a, b in zip(q, previous)], "effort": [], "pose": values[6:13]})
    return rows


def main() -> int:
    parser = argparse.ArgumentParser()
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--rows")
    source.add_argument("--csv")
    parser.add_argument("--count", type=int, default=5000)
    parser.add_argument("--namespace", required=True)
    parser.add_argument("--tf-prefix", default="")
    parser.add_argument("--rate-hz", type=float, default=250.0)
    parser.add_argument("--out", required=True)
    parser.add_argument("--match-timeout", type=float, default=30.0)
    parser.add_argument("--receive-timeout", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=20261203)
    args = parser.parse_args()
    if args.rows:
        with open(args.rows) as f:
            rows = json.load(f)
    else:
        rows = rows_from_csv(args.csv, args.count)

    rclpy.init()
    node = Node("ur_driver", namespace=args.namespace)
    joints_pub = node.create_publisher(JointState, "joint_states", QOS)
    pose_pub = node.create_publisher(PoseStamped, "tcp_pose_broadcaster/pose", QOS)
    received: list[dict] = []

    def on_twin_pose(msg: PoseStamped) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        received.append({
            "sec": msg.header.stamp.sec,
            "nanosec": msg.header.stamp.nanosec,
            "frame_id": msg.header.frame_id,
            "pose": [p.x, p.y, p.z, o.x, o.y, o.z, o.w],
        })

    node.create_subscription(PoseStamped, "armtwin/tcp_pose", on_twin_pose, QOS)

    def spin_until(predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                return False
            rclpy.spin_once(node, timeout_sec=0.05)
        return True

    # The bridge creates its DDS readers once a Zenoh subscriber (armtwin) matches, and its writer
    # of the twin pose once it sees this node's subscription: wait for both before publishing.
    sub_topic = node.resolve_topic_name("armtwin/tcp_pose")
    matched = spin_until(
        lambda: joints_pub.get_subscription_count() > 0
        and pose_pub.get_subscription_count() > 0
        and node.count_publishers(sub_topic) > 0,
        args.match_timeout,
    )
    say(matched=matched)
    if not matched:
        node.destroy_node()
        rclpy.shutdown()
        return 2

    rng = random.Random(args.seed)
    period_s = 1.0 / args.rate_hz
    next_at = time.monotonic()
    first_joint_bytes = first_pose_bytes = None
    for row in rows:
        js = joint_state(row, args.tf_prefix, rng)
        ps = pose_stamped(row, f"{args.tf_prefix}base")
        if first_joint_bytes is None:
            first_joint_bytes = serialize_message(js)
            first_pose_bytes = serialize_message(ps)
        joints_pub.publish(js)
        pose_pub.publish(ps)
        next_at += period_s
        # Serve the subscription while pacing, so twin poses are taken as they come.
        while (left := next_at - time.monotonic()) > 0:
            rclpy.spin_once(node, timeout_sec=left)
    say(published=len(rows))
    spin_until(lambda: len(received) >= len(rows), args.receive_timeout)

    hashes = {}
    for name, topic in (("joint_states", "joint_states"), ("pose", "tcp_pose_broadcaster/pose")):
        infos = node.get_publishers_info_by_topic(node.resolve_topic_name(topic))
        hashes[name] = str(infos[0].topic_type_hash) if infos else None
    with open(args.out, "w") as f:
        json.dump({
            "received": received,
            "type_hashes": hashes,
            "joint_state_bytes": first_joint_bytes.hex(),
            "pose_stamped_bytes": first_pose_bytes.hex(),
            "rclpy": rclpy.__file__,
        }, f)
    say(received=len(received))
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
