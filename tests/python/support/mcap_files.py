"""armtwin's MCAP files (the flight recorder's incidents, ``armtwin record``'s recordings) read
back with the independent readers: the ``mcap`` package and ``mcap-ros2-support``."""

from __future__ import annotations

from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

# Every armtwin file's channels, and their schemas (docs/recorder.md).
TOPICS = {
    "/joint_states": "sensor_msgs/msg/JointState",
    "/twin/pose": "geometry_msgs/msg/PoseStamped",
    "/tcp_pose_broadcaster/pose": "geometry_msgs/msg/PoseStamped",
    "/twin/deviation": "armtwin_msgs/msg/Deviation",
    "/twin/effort": "armtwin_msgs/msg/Effort",
    "/rosout": "rcl_interfaces/msg/Log",
}


def read_mcap(path: Path):
    """(channels {topic: (schema name, schema encoding, message encoding)}, decoded messages by
    topic as (log time, message, raw bytes), metadata by name)."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        channels = {
            c.topic: (summary.schemas[c.schema_id].name, summary.schemas[c.schema_id].encoding, c.message_encoding)
            for c in summary.channels.values()
        }
        messages: dict[str, list] = {topic: [] for topic in channels}
        for _, channel, message, decoded in reader.iter_decoded_messages():
            messages[channel.topic].append((message.log_time, decoded, message.data))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return channels, messages, metadata


def stamp_of(header) -> float:
    return seconds(header.stamp)


def seconds(time) -> float:
    """A ``builtin_interfaces/Time`` read back as armtwin's stamps are: sec + nanosec·1e-9."""
    return time.sec + time.nanosec * 1e-9
