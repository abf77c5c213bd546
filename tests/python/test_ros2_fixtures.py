"""The committed ROS 2 fixtures (tests/data/ros2) are what the pinned generators write.

Regenerates them with make_ros2_fixtures.py (rosbags and mcap-ros2-support) into a temporary
directory and compares every file byte for byte, then reads the committed bags back with rosbags'
own reader. The Rust tests use the committed files and need no Python.

The messages real rclpy serialized (tests/data/ros2/rclpy, captured once by
capture_rclpy_fixtures.py, not reproducible byte for byte) are compared with what rosbags writes
for the same fields: they differ only in alignment padding and in bytes after the message.

Run: ``.venv/bin/python -m pytest tests/python/test_ros2_fixtures.py -q``
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from support import ros2_fixtures as fixtures
from support.paths import DATA_DIR

ROS2_DIR = DATA_DIR / "ros2"


RCLPY_DIR = ROS2_DIR / "rclpy"


def relative_files(root: Path) -> list[Path]:
    """The generated files: everything but the rclpy captures."""
    files = (p.relative_to(root) for p in root.rglob("*") if p.is_file())
    return sorted(p for p in files if p.parts[0] != RCLPY_DIR.name)


def test_regenerated_fixtures_are_the_committed_ones(tmp_path: Path) -> None:
    fixtures.main(tmp_path)
    assert relative_files(tmp_path) == relative_files(ROS2_DIR)
    for name in relative_files(ROS2_DIR):
        assert (tmp_path / name).read_bytes() == (ROS2_DIR / name).read_bytes(), name


def test_valid_messages_read_back_in_rosbags() -> None:
    manifest = json.loads((ROS2_DIR / "messages.json").read_text())
    for entry in manifest:
        if "error" in entry:
            continue
        data = (ROS2_DIR / entry["file"]).read_bytes()
        message = fixtures.TYPESTORE.deserialize_cdr(data, entry["type"])
        stamp = message.header.stamp
        assert stamp.sec + stamp.nanosec * 1e-9 == entry["stamp_s"], entry["file"]
        if entry["type"] == "sensor_msgs/msg/JointState":
            prefix = entry["tf_prefix"]
            q = fixtures.model_order(message.name, message.position, prefix)
            assert q == entry["q_rad"], entry["file"]


def test_bags_hold_the_csv_rows() -> None:
    header, rows = fixtures.head_rows()
    for name in ("ur10e_lasttest_head_mcap", "ur10e_lasttest_head_sqlite3"):
        with AnyReader([ROS2_DIR / name], default_typestore=fixtures.TYPESTORE) as reader:
            joints = [
                reader.deserialize(raw, c.msgtype)
                for c, _, raw in reader.messages()
                if c.topic == fixtures.JOINT_TOPIC
            ]
        assert len(joints) == len(rows) == fixtures.BAG_ROWS, name
        for message, row in zip(joints, rows):
            q = fixtures.model_order(message.name, message.position)
            assert q == [float(cell) for cell in row[1:7]], name


def rosbags_bytes(entry: dict) -> bytes:
    """The same message as rosbags serializes it."""
    ts = fixtures.TYPESTORE.types
    header = ts["std_msgs/msg/Header"](
        stamp=ts["builtin_interfaces/msg/Time"](sec=entry["sec"], nanosec=entry["nanosec"]),
        frame_id=entry.get("frame_id", ""),
    )
    if entry["type"] == "sensor_msgs/msg/JointState":
        sent = entry["sent"]
        message = ts["sensor_msgs/msg/JointState"](
            header=header,
            name=sent["name"],
            position=np.array(sent["position"], dtype=np.float64),
            velocity=np.array(sent["velocity"], dtype=np.float64),
            effort=np.array(sent["effort"], dtype=np.float64),
        )
    else:
        x, y, z = entry["position_m"]
        qx, qy, qz, qw = entry["quaternion_xyzw"]
        message = ts["geometry_msgs/msg/PoseStamped"](
            header=header,
            pose=ts["geometry_msgs/msg/Pose"](
                position=ts["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                orientation=ts["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
            ),
        )
    return bytes(fixtures.TYPESTORE.serialize_cdr(message, entry["type"]))


def test_rclpy_bytes_differ_from_rosbags_only_in_padding_and_tail() -> None:
    manifest = json.loads((RCLPY_DIR / "messages.json").read_text())
    padding_seen = tail_seen = 0
    for entry in manifest:
        real = (RCLPY_DIR / entry["file"]).read_bytes()
        reference = rosbags_bytes(entry)
        assert len(real) >= len(reference), entry["file"]
        differing = [i for i in range(len(reference)) if real[i] != reference[i]]
        # Where they differ, rosbags wrote a zero: padding (rclpy leaves it uninitialised).
        assert all(reference[i] == 0 for i in differing), (entry["file"], differing)
        padding_seen += bool(differing)
        tail_seen += len(real) > len(reference)
    # What the captures show, and why a decoder must not judge padding nor the bytes after a
    # message: if a new capture showed neither, this test would no longer prove anything.
    assert padding_seen > 0 and tail_seen > 0, (padding_seen, tail_seen)
