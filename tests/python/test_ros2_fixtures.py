"""The committed ROS 2 fixtures (tests/data/ros2) are what the pinned generators write.

Regenerates them with make_ros2_fixtures.py (rosbags and mcap-ros2-support) into a temporary
directory and compares every file byte for byte, then reads the committed bags back with rosbags'
own reader. The Rust tests use the committed files and need no Python.

Run: ``.venv/bin/python -m pytest tests/python/test_ros2_fixtures.py -q``
"""

from __future__ import annotations

import json
from pathlib import Path

import make_ros2_fixtures as fixtures
from conftest import DATA_DIR
from rosbags.highlevel import AnyReader

ROS2_DIR = DATA_DIR / "ros2"


def relative_files(root: Path) -> list[Path]:
    return sorted(p.relative_to(root) for p in root.rglob("*") if p.is_file())


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
