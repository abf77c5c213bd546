"""`armtwin record` end to end: the real service twins the first rows of the real UR10e recording
(tests/data/ur10e_lasttest.csv) streamed by `armtwin replay`, while `armtwin record` writes what
went over the mesh to an MCAP file. The file is read back with the `mcap` package and
`mcap-ros2-support`; `armtwin validate` of the file gives the metrics it gives of the CSV, and
`armtwin replay` of the file as another robot makes the service compute them once more.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_record.py -q``
"""

from __future__ import annotations

import json
import struct
import time

from support.mcap_files import TOPICS, read_mcap, stamp_of
from support.paths import DATA_DIR
from support.process import ArmtwinProcess, Process, run_armtwin, wait_until
from support.zenoh_clients import get_json, open_session

# Rows of the recording streamed: a few seconds of the arm moving, a few seconds of test.
ROWS = 4000

CONFIG = """
[service]
metrics_period_ms = 50
pose_congestion = "block"

[recorder]
enabled = false

[robots.default]
model = "ur10e"
"""

# The report's parts that say which file was read; every other part must be the same.
NAMING = {"recording", "format"}


def first_rows(path) -> list[list[str]]:
    """The CSV's first ROWS data rows, as text fields; the file with them written to ``path``."""
    lines = (DATA_DIR / "ur10e_lasttest.csv").read_text().splitlines()[: ROWS + 1]
    path.write_text("\n".join(lines) + "\n")
    return [line.split(",") for line in lines[1:]]


def start_recorder(armtwin_bin, tmp_path, service: ArmtwinProcess, *args) -> Process:
    """``armtwin record ARGS -e <service>``, a client of the service (the default), which routes
    every robot's streams to it; returned once it has subscribed."""
    recorder = Process("record", [armtwin_bin, "record", *args, "-e", service.endpoint], tmp_path,
                       watchdog_s=120.0)
    recorder.start()
    assert recorder.wait_log("recording started"), recorder.logs()
    return recorder


def report(out) -> dict:
    return json.loads((out / "report.json").read_text())


def test_a_recording_reads_back_and_replays_to_the_same_metrics(armtwin_bin, tmp_path):
    csv = tmp_path / "rows.csv"
    rows = first_rows(csv)
    service = ArmtwinProcess(armtwin_bin, tmp_path, CONFIG, 120.0).start()
    out = tmp_path / "recordings"
    recorder = session = None
    try:
        recorder = start_recorder(armtwin_bin, tmp_path, service, "r1", "-o", out)
        res = run_armtwin("replay", csv, "--robot", "r1", "-e", service.endpoint, "--max-rate")
        assert res.returncode == 0, res.stderr
        # The replay returns once the service has taken every message, and the service has
        # passed each on to the recorder as it took it: what is left is loopback transit.
        time.sleep(1.0)
        stopped = recorder.stop()
        assert stopped.code == 0, recorder.logs()
        assert "0 messages dropped (queue full), 0 malformed" in recorder.logs(), recorder.logs()

        path = out / "r1.mcap"
        channels, messages, metadata = read_mcap(path)
        assert channels == {topic: (name, "ros2msg", "cdr") for topic, name in TOPICS.items()}, channels
        meta = metadata["armtwin"]
        assert meta["robot"] == "r1" and meta["trigger"] == "record" and meta["armtwin_version"], meta
        for topic in ("/joint_states", "/tcp_pose_broadcaster/pose", "/twin/pose", "/twin/deviation"):
            assert len(messages[topic]) == ROWS, (topic, len(messages[topic]))
            assert [log_time for log_time, _, _ in messages[topic]] == [
                m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m, _ in messages[topic]
            ], topic
        assert messages["/twin/effort"] == [] and messages["/rosout"] == []
        stamps = [stamp_of(m.header) for _, m, _ in messages["/joint_states"]]
        assert all(a < b for a, b in zip(stamps, stamps[1:]))
        # The twin's outputs carry the stamps of the joint samples they came from.
        assert [stamp_of(m.header) for _, m, _ in messages["/twin/pose"]] == stamps
        assert [stamp_of(m.header) for _, m, _ in messages["/tcp_pose_broadcaster/pose"]] == stamps
        assert (float(meta["from_s"]), float(meta["until_s"])) == (stamps[0], stamps[-1])
        for (_, joint_state, _), (_, pose, _), row in zip(
            messages["/joint_states"], messages["/tcp_pose_broadcaster/pose"], rows
        ):
            sent = struct.pack("<6d", *(float(v) for v in row[1:7]))
            assert struct.pack("<6d", *joint_state.position) == sent, row
            p, o = pose.pose.position, pose.pose.orientation
            # The measured pose as the gateway sent it: its quaternion not normalised.
            assert [p.x, p.y, p.z, o.x, o.y, o.z, o.w] == [float(v) for v in row[7:14]], row

        # `validate` reads the file as a bag of the robot: the metrics of the CSV, to the bit.
        of_file, of_csv = tmp_path / "of-file", tmp_path / "of-csv"
        for source, into in ((path, of_file), (csv, of_csv)):
            res = run_armtwin("validate", source, "--out", into)
            assert res.returncode == 0, res.stderr
        expected = report(of_csv)
        assert expected["paired"] == ROWS, expected["paired"]
        got = report(of_file)
        assert {k: v for k, v in got.items() if k not in NAMING} == {
            k: v for k, v in expected.items() if k not in NAMING
        }
        cumulative = expected["cumulative"]
        # The deviations the service published live, as recorded, are validate's.
        live = [m.position_m for _, m, _ in messages["/twin/deviation"]]
        assert max(live) == cumulative["position"]["max"]

        # The file replayed as another robot: the service pairs every sample again, with the
        # same deviations.
        res = run_armtwin("replay", path, "--robot", "r2", "-e", service.endpoint, "--max-rate")
        assert res.returncode == 0, res.stderr
        session = open_session(service.endpoint)
        state = lambda: get_json(session, "twin/state/r2")[0][1]["metrics"]  # noqa: E731
        assert wait_until(lambda: state()["paired"] == ROWS, 10.0, 0.1), state()
        metrics = state()
        for part in ("position", "angle"):
            assert metrics["cumulative"][part] == cumulative[part], (part, metrics["cumulative"][part])
        assert metrics["cumulative"]["n"] == cumulative["n"]
    finally:
        if session is not None:
            session.close()
        if recorder is not None:
            recorder.stop()
        service.stop()


def test_robots_beyond_the_bound_are_refused_and_malformed_messages_skipped(armtwin_bin, tmp_path):
    service = ArmtwinProcess(armtwin_bin, tmp_path, CONFIG, 120.0).start()
    out = tmp_path / "recordings"
    recorder = session = None
    try:
        # Another prefix than the service's: the service routes these keys, twins none of them.
        recorder = start_recorder(armtwin_bin, tmp_path, service, "**", "-o", out, "--prefix", "elsewhere",
                                  "--max-robots", "2")
        session = open_session(service.endpoint)
        q = [0.1, -1.2, 1.3, -0.4, 1.5, 0.6]
        sent = [("cell-1/r1", 3), ("r2", 2), ("r3", 1)]
        for robot, count in sent:
            for i in range(count):
                session.put(f"elsewhere/joints/{robot}", json.dumps({"t": 100.0 + i, "q": q}))
        session.put("elsewhere/joints/cell-1/r1", "{not json")
        session.put("elsewhere/joints/r2", json.dumps({"t": 200.0, "q": q[:5]}))
        # What is left after the puts is loopback transit through the service.
        time.sleep(1.0)
        stopped = recorder.stop()
        assert stopped.code == 0, recorder.logs()
    finally:
        if session is not None:
            session.close()
        if recorder is not None:
            recorder.stop()
        service.stop()
    logs = recorder.logs()
    assert "recorded 2 robots; 0 messages dropped (queue full), 2 malformed, 1 of refused robots" in logs, logs
    assert sorted(p.name for p in out.iterdir()) == ["cell-1%2Fr1.mcap", "r2.mcap"]
    for name, count in (("cell-1%2Fr1.mcap", 3), ("r2.mcap", 2)):
        _, messages, metadata = read_mcap(out / name)
        assert len(messages["/joint_states"]) == count, name
        assert [stamp_of(m.header) for _, m, _ in messages["/joint_states"]] == [100.0 + i for i in range(count)]
        assert metadata["armtwin"]["from_s"] == "100", metadata
