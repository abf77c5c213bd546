"""ROS 2 robots live, end to end: ``armtwin serve`` with ``[[sources]]`` on ROS 2 keys.

A Python Zenoh peer plays a UR driver: ``sensor_msgs/JointState`` (joint names shuffled per
message, a ``tf_prefix``, a gripper joint now and then) and ``geometry_msgs/PoseStamped`` in
``<tf_prefix>base``, CDR-encoded by ``rosbags``, from rows of ``tests/data/ur10e_lasttest.csv``:

* robot ``alice`` on ``rmw_zenoh`` keys (``0/alice/joint_states/<type>/<hash>``) with the
  ``rmw_zenoh`` attachment written by ``zenoh.ext`` (one sequence number skipped);
* robot ``bob`` on ``zenoh-bridge-ros2dds`` keys (``bob/joint_states``), no attachment;
* robot ``json_ref``: the same rows as armtwin's JSON messages on ``twin/joints|measured``.

Twin poses and final metrics are checked against the numpy reference (ur_reference.py) and
against the JSON path (bit for bit); the skipped sequence number must raise one ``gap`` event; the
twin pose armtwin publishes for ROS tools is decoded by ``rosbags`` and its attachment by
``zenoh.ext``.

Run: ``.venv/bin/python -m pytest tests/python/test_ros2_live.py -q``.
"""

from __future__ import annotations

import csv
import random
import threading
import time

import numpy as np
import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore
from zenoh.ext import Int64, z_deserialize, z_serialize

from support.checks import Checks
from support.paths import DATA_DIR
from support.process import ArmtwinProcess, wait_until
from support.twin_reference import (
    check_deviations,
    check_metrics,
    check_poses,
    reference_deviations,
    reference_stats,
)
from support.ur_joints import UR_JOINTS
from support.zenoh_clients import TwinClient

ROWS = 1000
RATE_HZ = 500
EPOCH_SEC = 1_748_954_669
SKIPPED_AFTER = 500  # alice's attachment jumps from seq 500 to 502
WATCHDOG_S = 120.0

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
JointState = TYPESTORE.types["sensor_msgs/msg/JointState"]
PoseStamped = TYPESTORE.types["geometry_msgs/msg/PoseStamped"]
Header = TYPESTORE.types["std_msgs/msg/Header"]
Time = TYPESTORE.types["builtin_interfaces/msg/Time"]
Pose = TYPESTORE.types["geometry_msgs/msg/Pose"]
Point = TYPESTORE.types["geometry_msgs/msg/Point"]
Quaternion = TYPESTORE.types["geometry_msgs/msg/Quaternion"]

JOINT_DDS = "sensor_msgs::msg::dds_::JointState_"
POSE_DDS = "geometry_msgs::msg::dds_::PoseStamped_"
JOINT_HASH = TYPESTORE.hash_rihs01("sensor_msgs/msg/JointState")
POSE_HASH = TYPESTORE.hash_rihs01("geometry_msgs/msg/PoseStamped")

CONFIG = f"""\
[service]
metrics_period_ms = 50
# Every pose is counted: a test client that falls behind must slow the twin, not miss poses.
pose_congestion = "block"

[robots.default]
model = "ur10e"
[robots.default.ros2_pose]          # every robot's twin pose for ROS tools, rmw_zenoh keys
scheme = "rmw_zenoh"
tf_prefix = "alice_"
[robots.bob.ros2_pose]              # bob's through the bridge
scheme = "bridge"
tf_prefix = ""
[robots.json_ref.ros2_pose]
enabled = false

[[sources]]
key = "0/**/joint_states/{JOINT_DDS}/*"
codec = "ros2"
stream = "joints"
scheme = "rmw_zenoh"
robot_from_key = "ros2_namespace"
tf_prefix = "alice_"
[[sources]]
key = "0/**/tcp_pose_broadcaster/pose/{POSE_DDS}/*"
codec = "ros2"
stream = "measured"
scheme = "rmw_zenoh"
robot_from_key = "ros2_namespace"
tf_prefix = "alice_"

[[sources]]
key = "*/joint_states"
codec = "ros2"
stream = "joints"
scheme = "bridge"
robot_from_key = "ros2_namespace"
[[sources]]
key = "*/tcp_pose_broadcaster/pose"
codec = "ros2"
stream = "measured"
scheme = "bridge"
robot_from_key = "ros2_namespace"
"""


def load_rows():
    """The first ROWS rows: joints (N,6), measured x,y,z,qx,qy,qz,qw (N,7), stamps at 500 Hz as
    (sec, nanosec) and the seconds a ROS 2 stamp reads as (sec + nanosec · 1e-9)."""
    with open(DATA_DIR / "ur10e_lasttest.csv", newline="") as f:
        reader = csv.reader(f)
        next(reader)
        rows = [[float(v) for v in row[1:14]] for _, row in zip(range(ROWS), reader)]
    data = np.array(rows, float)
    stamps = []
    for i in range(ROWS):
        ns = i * (1_000_000_000 // RATE_HZ)
        stamps.append((EPOCH_SEC + ns // 1_000_000_000, ns % 1_000_000_000))
    t = [float(sec) + float(nanosec) * 1e-9 for sec, nanosec in stamps]
    return data[:, :6], data[:, 6:13], stamps, t


def joint_state(stamp, q, tf_prefix, rng):
    """The UR driver's JointState: names (with tf_prefix) in a shuffled order, every third message
    with a gripper joint too."""
    entries = [(f"{tf_prefix}{name}", float(value)) for name, value in zip(UR_JOINTS, q)]
    if rng.random() < 1 / 3:
        entries.append((f"{tf_prefix}gripper_joint", 0.02))
    rng.shuffle(entries)
    msg = JointState(
        header=Header(stamp=Time(sec=stamp[0], nanosec=stamp[1]), frame_id=""),
        name=[name for name, _ in entries],
        position=np.array([value for _, value in entries], dtype=np.float64),
        velocity=np.zeros(len(entries)),
        effort=np.array([], dtype=np.float64),
    )
    return bytes(TYPESTORE.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def pose_stamped(stamp, meas, frame_id):
    x, y, z, qx, qy, qz, qw = (float(v) for v in meas)
    msg = PoseStamped(
        header=Header(stamp=Time(sec=stamp[0], nanosec=stamp[1]), frame_id=frame_id),
        pose=Pose(position=Point(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw)),
    )
    return bytes(TYPESTORE.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))


def rmw_attachment(seq, gid):
    return z_serialize((Int64(seq), Int64(time.time_ns()), gid)).to_bytes()


class RosSamples:
    """Samples (key, payload, attachment) of the twin pose outputs, from the Zenoh callback."""

    def __init__(self):
        self.lock = threading.Lock()
        self.items = []

    def __call__(self, sample: zenoh.Sample) -> None:
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
        with self.lock:
            self.items.append((str(sample.key_expr), sample.payload.to_bytes(), attachment))

    def on(self, key):
        with self.lock:
            return [(payload, attachment) for k, payload, attachment in self.items if k == key]


@pytest.fixture
def service(armtwin_bin, tmp_path):
    proc = ArmtwinProcess(armtwin_bin, tmp_path, CONFIG, WATCHDOG_S)
    proc.start()
    client = None
    try:
        client = TwinClient(proc.endpoint)
        yield proc, client
    finally:
        code, _ = proc.stop()
        if client is not None:
            client.close()
    if proc.watchdog_fired:
        pytest.fail(f"watchdog: armtwin killed after {WATCHDOG_S} s\n{proc.logs()}")
    if code != 0:
        pytest.fail(f"armtwin exited with code {code} after SIGINT\n{proc.logs()}")


def test_ur_driver_on_rmw_zenoh_and_bridge_keys_twins_as_the_json_path(service):
    proc, client = service
    q, meas, stamps, t = load_rows()
    keys = {
        "alice": (
            f"0/alice/joint_states/{JOINT_DDS}/{JOINT_HASH}",
            f"0/alice/tcp_pose_broadcaster/pose/{POSE_DDS}/{POSE_HASH}",
        ),
        "bob": ("bob/joint_states", "bob/tcp_pose_broadcaster/pose"),
        "json_ref": ("twin/joints/json_ref", "twin/measured/json_ref"),
    }
    ros_out = RosSamples()
    ros_subscribers = [
        client.session.declare_subscriber("0/**/armtwin/tcp_pose/**", ros_out),
        client.session.declare_subscriber("*/armtwin/tcp_pose", ros_out),
    ]
    publishers = {robot: [client.publisher(k) for k in pair] for robot, pair in keys.items()}
    every = [p for pair in publishers.values() for p in pair]
    assert wait_until(lambda: all(p.matching_status.matching for p in every), 15.0), [
        str(p.key_expr) for p in every if not p.matching_status.matching
    ]
    client.ready([])

    rng = random.Random(20251201)
    alice_gid = bytes(rng.randrange(256) for _ in range(16))
    started_ns = time.time_ns()
    for i in range(ROWS):
        seq = i + 1 if i < SKIPPED_AFTER else i + 2
        joints, poses = publishers["alice"]
        joints.put(joint_state(stamps[i], q[i], "alice_", rng), attachment=rmw_attachment(seq, alice_gid))
        poses.put(pose_stamped(stamps[i], meas[i], "alice_base"), attachment=rmw_attachment(i + 1, alice_gid))
        joints, poses = publishers["bob"]
        joints.put(joint_state(stamps[i], q[i], "", rng))
        poses.put(pose_stamped(stamps[i], meas[i], "base"))
        joints, poses = publishers["json_ref"]
        client.put_json(joints, {"t": t[i], "q": [float(v) for v in q[i]]})
        measured = dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), map(float, meas[i])))
        client.put_json(poses, {"t": t[i], **measured})

    c = client.collector
    done = wait_until(
        lambda: all(
            (m := c.last("metrics", robot)) is not None and m.get("paired") == ROWS
            for robot in keys
        ),
        30.0,
    )
    assert done, ({robot: c.last("metrics", robot) for robot in keys}, proc.logs(2000))
    alice_out = f"0/alice/armtwin/tcp_pose/{POSE_DDS}/{POSE_HASH}"
    assert wait_until(lambda: len(ros_out.on(alice_out)) == ROWS, 10.0)
    assert wait_until(lambda: len(ros_out.on("bob/armtwin/tcp_pose")) == ROWS, 10.0)
    time.sleep(0.2)  # anything surplus arrives

    checks = Checks()
    stats = reference_stats(reference_deviations(q, meas))
    poses = {robot: c.messages("pose", robot) for robot in keys}
    for robot in keys:
        check_poses(checks, poses[robot], robot, t, q, robot)
        check_deviations(checks, c.messages("deviation", robot), robot, t, q, meas, robot)
        check_metrics(checks, c.last("metrics", robot), robot, ROWS, 0, stats, robot, t=t[-1])
    fields = ("t", "seq", "x", "y", "z", "qx", "qy", "qz", "qw", "roll", "pitch", "yaw")
    reference = [[p[k] for k in fields] for p in poses["json_ref"]]
    for robot in ("alice", "bob"):
        got = [[p[k] for k in fields] for p in poses[robot]]
        checks.equal(got, reference, f"{robot}: poses as the JSON path's")
        for part in ("paired", "unpaired", "rejected", "cumulative", "window"):
            checks.equal(
                c.last("metrics", robot)[part],
                c.last("metrics", "json_ref")[part],
                f"{robot}: metrics {part} as the JSON path's",
            )

    events = {robot: c.messages("events", robot) for robot in keys}
    checks.equal(
        [(e["kind"], e["detail"]) for e in events["alice"]],
        [("gap", {"expected": SKIPPED_AFTER + 1, "got": SKIPPED_AFTER + 2})],
        "alice: the skipped sequence number is a gap, and the only event",
    )
    gap_t = events["alice"][0]["t"] if events["alice"] else None
    checks.equal(gap_t, t[SKIPPED_AFTER], "alice: the gap at its sample's stamp")
    checks.equal(events["bob"], [], "bob: no events")
    checks.equal(events["json_ref"], [], "json_ref: no events")

    # The twin pose for ROS tools, read by rosbags and zenoh.ext.
    for robot, key, frame_id, attached in (
        ("alice", alice_out, "alice_base", True),
        ("bob", "bob/armtwin/tcp_pose", "base", False),
    ):
        samples = ros_out.on(key)
        checks.equal(len(samples), ROWS, f"{robot}: PoseStamped samples")
        decoded = [TYPESTORE.deserialize_cdr(p, "geometry_msgs/msg/PoseStamped") for p, _ in samples]
        checks.true(all(m.header.frame_id == frame_id for m in decoded), f"{robot}: frame_id {frame_id}")
        header_stamps = [(m.header.stamp.sec, m.header.stamp.nanosec) for m in decoded]
        checks.equal(header_stamps, stamps, f"{robot}: header.stamp as the JointState's")
        got = [
            [m.pose.position.x, m.pose.position.y, m.pose.position.z,
             m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w]
            for m in decoded
        ]
        want = [[p[k] for k in ("x", "y", "z", "qx", "qy", "qz", "qw")] for p in poses[robot]]
        checks.equal(got, want, f"{robot}: PoseStamped pose = twin pose")
        attachments = [a for _, a in samples]
        if not attached:
            checks.true(all(a is None for a in attachments), f"{robot}: no attachment (bridge)")
            continue
        parsed = [z_deserialize(tuple[Int64, Int64, bytes], zenoh.ZBytes(a)) for a in attachments]
        checks.equal([seq for seq, _, _ in parsed], list(range(1, ROWS + 1)), f"{robot}: attachment seq")
        now_ns = time.time_ns()
        checks.true(all(started_ns <= ts <= now_ns for _, ts, _ in parsed), f"{robot}: source times")
        checks.equal({len(gid) for _, _, gid in parsed}, {16}, f"{robot}: 16-byte gid")
        checks.equal(len({gid for _, _, gid in parsed}), 1, f"{robot}: one gid")
    checks.equal([k for k, _, _ in ros_out.items if "json_ref" in k], [], "json_ref: ros2_pose disabled")
    for subscriber in ros_subscribers:
        subscriber.undeclare()
    checks.done(proc.logs())
