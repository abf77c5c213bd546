"""The ROS 2 fixtures in tests/data/ros2/, written with implementations independent of armtwin.

CDR messages are serialised by `rosbags` and, for every little-endian one, also by
`mcap-ros2-support` (a separate serializer): the two must give the same bytes. Damaged messages
(truncated, an absurd count, an XCDR2 header) are valid ones with bytes cut or patched here.
`messages.json` lists every message with what a decoder must read from it (or the kind of error).

The two bags (MCAP and sqlite3, rosbag2 version 9) hold the first rows of
tests/data/ur10e_lasttest.csv as `/joint_states` and `/tcp_pose_broadcaster/pose`, with 500 Hz
stamps inside each recorded second; `ur10e_lasttest_head.csv` is the same rows as a ROS 2 export
with `header.stamp.nanosec`, so a bag and its CSV can be validated side by side.

test_ros2_fixtures.py writes them again and compares; ``tools/make_ros2_fixtures.py`` writes them:

    .venv/bin/python tools/make_ros2_fixtures.py [OUTPUT_DIR]   (default: tests/data/ros2)
"""

from __future__ import annotations

import csv
import json
import shutil
import struct
from pathlib import Path

import numpy as np
from mcap_ros2._dynamic import serialize_dynamic
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from support.paths import DATA_DIR
from support.ur_joints import DRIVER_ORDER, UR_JOINTS

CSV_PATH = DATA_DIR / "ur10e_lasttest.csv"
DEFAULT_OUTPUT = DATA_DIR / "ros2"

BAG_ROWS = 400
RATE_HZ = 500
JOINT_TOPIC = "/joint_states"
POSE_TOPIC = "/tcp_pose_broadcaster/pose"

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
JointState = TYPESTORE.types["sensor_msgs/msg/JointState"]
PoseStamped = TYPESTORE.types["geometry_msgs/msg/PoseStamped"]
Header = TYPESTORE.types["std_msgs/msg/Header"]
Time = TYPESTORE.types["builtin_interfaces/msg/Time"]
Pose = TYPESTORE.types["geometry_msgs/msg/Pose"]
Point = TYPESTORE.types["geometry_msgs/msg/Point"]
Quaternion = TYPESTORE.types["geometry_msgs/msg/Quaternion"]


def mcap_ros2_encoder(typename: str):
    text, _ = TYPESTORE.generate_msgdef(typename, ros_version=2)
    return serialize_dynamic(typename, text)[typename]


ENCODE_JOINT_STATE = mcap_ros2_encoder("sensor_msgs/msg/JointState")
ENCODE_POSE_STAMPED = mcap_ros2_encoder("geometry_msgs/msg/PoseStamped")


def header(sec: int, nanosec: int, frame_id: str):
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def joint_state(sec, nanosec, frame_id, names, position, velocity=(), effort=()):
    return JointState(
        header=header(sec, nanosec, frame_id),
        name=list(names),
        position=np.array(position, dtype=np.float64),
        velocity=np.array(velocity, dtype=np.float64),
        effort=np.array(effort, dtype=np.float64),
    )


def pose_stamped(sec, nanosec, frame_id, position, xyzw):
    x, y, z = position
    qx, qy, qz, qw = xyzw
    return PoseStamped(
        header=header(sec, nanosec, frame_id),
        pose=Pose(position=Point(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw)),
    )


def as_dict(message) -> dict:
    """The message as the plain dict `mcap-ros2-support` serialises."""
    if hasattr(message, "__dataclass_fields__"):
        return {name: as_dict(getattr(message, name)) for name in message.__dataclass_fields__}
    if isinstance(message, np.ndarray):
        return message.tolist()
    return message


def serialize(message, little_endian: bool = True) -> bytes:
    """CDR with its 4-byte header, from rosbags; checked against mcap-ros2-support."""
    data = bytes(TYPESTORE.serialize_cdr(message, message.__msgtype__, little_endian=little_endian))
    if little_endian:
        encode = (
            ENCODE_JOINT_STATE
            if message.__msgtype__ == "sensor_msgs/msg/JointState"
            else ENCODE_POSE_STAMPED
        )
        second = bytes(encode(as_dict(message)))
        if second != data:
            raise SystemExit(f"rosbags and mcap-ros2-support disagree on {message}")
    return data


def model_order(names, position, tf_prefix=""):
    by_name = dict(zip(names, position))
    return [by_name[tf_prefix + joint] for joint in UR_JOINTS]


def message_fixtures() -> list[tuple[str, bytes, dict]]:
    """(file name, bytes, what a decoder must read) for every single-message fixture."""
    sec, nanosec = 1748954669, 250_000_000
    stamp_s = sec + nanosec * 1e-9
    q = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]
    shuffled = [UR_JOINTS[i] for i in DRIVER_ORDER]
    shuffled_q = [q[i] for i in DRIVER_ORDER]
    velocity = [0.01, -0.02, 0.03, -0.04, 0.05, -0.06]
    effort = [1.5, -2.5, 3.5, -4.5, 5.5, -6.5]

    fixtures = []

    def joints(name, ros_message, tf_prefix="", little_endian=True, **expect):
        data = serialize(ros_message, little_endian)
        entry = {"type": "sensor_msgs/msg/JointState", "tf_prefix": tf_prefix}
        entry.update(expect)
        fixtures.append((name, data, entry))
        return data

    joints(
        "joint_state_driver_order.cdr",
        joint_state(sec, nanosec, "", shuffled, shuffled_q, velocity, effort),
        stamp_s=stamp_s,
        q_rad=q,
    )
    prefixed = ["alice_" + n for n in shuffled] + ["alice_robotiq_85_left_knuckle_joint"]
    joints(
        "joint_state_tf_prefix_gripper.cdr",
        # A non-empty frame_id of odd length shifts every later field's alignment.
        joint_state(sec, nanosec, "alice_base_link", prefixed, [*shuffled_q, 0.42]),
        tf_prefix="alice_",
        stamp_s=stamp_s,
        q_rad=q,
    )
    joints(
        "joint_state_empty_effort.cdr",
        # An empty last sequence: its count ends the message, with no padding after it.
        joint_state(sec, nanosec, "", shuffled, shuffled_q, velocity),
        stamp_s=stamp_s,
        q_rad=q,
    )
    empty = joints(
        "joint_state_empty_velocity_effort.cdr",
        joint_state(sec, nanosec, "", UR_JOINTS, q),
        stamp_s=stamp_s,
        q_rad=q,
    )
    joints(
        "joint_state_big_endian.cdr",
        joint_state(sec, nanosec, "base", shuffled, shuffled_q, velocity, effort),
        little_endian=False,
        stamp_s=stamp_s,
        q_rad=q,
    )
    without_wrist_2 = [n for n in shuffled if n != "wrist_2_joint"]
    joints(
        "joint_state_missing_joint.cdr",
        joint_state(
            sec,
            nanosec,
            "",
            without_wrist_2,
            [p for n, p in zip(shuffled, shuffled_q) if n != "wrist_2_joint"],
        ),
        error="missing_joint",
        message="missing joint 'wrist_2_joint'",
    )
    # Damaged copies of the message with empty velocity and effort.
    fixtures.append(
        (
            "joint_state_truncated.cdr",
            empty[:-12],
            {"type": "sensor_msgs/msg/JointState", "tf_prefix": "", "error": "truncated"},
        )
    )
    # Header 4, stamp 8, frame_id "" (length 4, NUL, 3 padding): the name count is at byte 20.
    huge = bytearray(empty)
    if struct.unpack_from("<I", huge, 20)[0] != 6:
        raise SystemExit("the name count is not where expected")
    struct.pack_into("<I", huge, 20, 0xFFFF_FFF0)
    fixtures.append(
        (
            "joint_state_huge_count.cdr",
            bytes(huge),
            {"type": "sensor_msgs/msg/JointState", "tf_prefix": "", "error": "count"},
        )
    )
    xcdr2 = bytearray(empty)
    xcdr2[0:2] = b"\x00\x07"
    fixtures.append(
        (
            "joint_state_xcdr2_header.cdr",
            bytes(xcdr2),
            {"type": "sensor_msgs/msg/JointState", "tf_prefix": "", "error": "representation"},
        )
    )

    position = [-0.807, 0.436, 0.42]
    xyzw = [-0.408, -0.9, -0.014, 0.152]
    for name, frame_id, little_endian in [
        ("pose_stamped_base.cdr", "base", True),
        ("pose_stamped_big_endian.cdr", "alice_base", False),
    ]:
        fixtures.append(
            (
                name,
                serialize(pose_stamped(sec, nanosec, frame_id, position, xyzw), little_endian),
                {
                    "type": "geometry_msgs/msg/PoseStamped",
                    "frame_id": frame_id,
                    "stamp_s": stamp_s,
                    "position_m": position,
                    "quaternion_xyzw": xyzw,
                },
            )
        )
    # What armtwin's encoder must write for this twin pose (a unit quaternion with qw >= 0).
    twin_xyzw = [0.5, -0.5, 0.5, 0.5]
    fixtures.append(
        (
            "pose_stamped_twin.cdr",
            serialize(pose_stamped(sec, 500_000_000, "base", position, twin_xyzw)),
            {
                "type": "geometry_msgs/msg/PoseStamped",
                "encode": True,
                "frame_id": "base",
                "stamp_s": sec + 0.5,
                "position_m": position,
                "quaternion_xyzw": twin_xyzw,
            },
        )
    )
    return fixtures


def head_rows() -> list[list[str]]:
    with CSV_PATH.open(newline="") as file:
        rows = list(csv.reader(file))
    return rows[0], rows[1 : BAG_ROWS + 1]


def stamped_rows():
    """(sec, nanosec, row) for the first rows, 500 Hz within each recorded second."""
    header_row, rows = head_rows()
    if header_row[0] != "header.stamp.sec":
        raise SystemExit(f"unexpected header in {CSV_PATH}")
    previous, k = None, 0
    for row in rows:
        sec = int(row[0])
        k = k + 1 if sec == previous else 0
        previous = sec
        yield sec, k * (1_000_000_000 // RATE_HZ), row


def write_head_csv(path: Path) -> None:
    header_row, _ = head_rows()
    with path.open("w", newline="") as file:
        writer = csv.writer(file, lineterminator="\n")
        writer.writerow([header_row[0], "header.stamp.nanosec", *header_row[1:]])
        for sec, nanosec, row in stamped_rows():
            writer.writerow([row[0], nanosec, *row[1:]])


def write_bag(path: Path, plugin: StoragePlugin) -> None:
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        joints = writer.add_connection(JOINT_TOPIC, JointState.__msgtype__, typestore=TYPESTORE)
        poses = writer.add_connection(POSE_TOPIC, PoseStamped.__msgtype__, typestore=TYPESTORE)
        for sec, nanosec, row in stamped_rows():
            values = [float(cell) for cell in row[1:]]
            q, position, xyzw = values[0:6], values[6:9], values[9:13]
            names = [UR_JOINTS[i] for i in DRIVER_ORDER]
            message = joint_state(
                sec, nanosec, "", names, [q[i] for i in DRIVER_ORDER], [0.0] * 6, [0.0] * 6
            )
            # The bag's log time is the recorder's receive time, a little after the stamp.
            received_ns = sec * 1_000_000_000 + nanosec + 150_000
            writer.write(joints, received_ns, serialize(message))
            pose = pose_stamped(sec, nanosec, "base", position, xyzw)
            writer.write(poses, received_ns + 20_000, serialize(pose))


def main(output: Path) -> None:
    output.mkdir(parents=True, exist_ok=True)
    manifest = []
    for name, data, entry in message_fixtures():
        (output / name).write_bytes(data)
        manifest.append({"file": name, **entry})
    (output / "messages.json").write_text(json.dumps(manifest, indent=2) + "\n")
    write_head_csv(output / "ur10e_lasttest_head.csv")
    for name, plugin in [
        ("ur10e_lasttest_head_mcap", StoragePlugin.MCAP),
        ("ur10e_lasttest_head_sqlite3", StoragePlugin.SQLITE3),
    ]:
        shutil.rmtree(output / name, ignore_errors=True)
        write_bag(output / name, plugin)
