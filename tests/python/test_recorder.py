"""The flight recorder end to end: the real service on real Zenoh streams the real UR10e recording
(tests/data/ur10e_lasttest.csv) with its measured pose pushed past the alarm threshold mid-stream;
the alarm leaves one MCAP file, read back with the `mcap` package and `mcap-ros2-support` (and the
joint messages once more with `rosbags`' CDR deserializer), against what was streamed. An
operator's record query works behind the shipped TLS + ACL router and a dashboard's is refused;
a recorder whose files cannot be written counts the failure and loses no twin sample.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_recorder.py -q``
"""

from __future__ import annotations

import json
import lzma
import re
import struct
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from support.gateway import Gateway
from support.mcap_files import TOPICS, read_mcap, seconds, stamp_of
from support.process import ArmtwinProcess, free_port, run_armtwin, wait_until
from support.secured_fleet import secured_fleet, stream_until_paired
from support.twin_reference import joint_message, load_lasttest_naive
from support.zenoh_clients import TwinClient, get_json, wait_queryable
from support.dashboard import metric

DATA = Path(__file__).resolve().parents[1] / "data"
PRE_S = 4.0
POST_S = 2.0
# Source time of the first row: the recording's own first stamp, so the files carry real Unix
# times; rows follow at 500 Hz.
T0 = 1748954669.0
PERIOD_S = 0.002
ROWS = 6000
# The measured pose is pushed 20 mm off (threshold 5 mm) for these rows (1.2 s, over the 0.5-s hold).
PUSHED = range(3000, 3600)


def config(recordings: Path, extra: str = "", recorder: str = "") -> str:
    return f"""
[service]
metrics_period_ms = 50
pose_congestion = "block"
{extra}

[recorder]
dir = "{recordings}"
pre_s = {PRE_S}
post_s = {POST_S}
{recorder}

[robots.default]
model = "ur10e"
alarm_position_m = 0.005
alarm_hold_s = 0.5
"""


def stream() -> tuple[list[float], list[list[float]], list[list[float]]]:
    """Stamps, joints and measured poses (the pushed rows 20 mm off in x) of the first rows."""
    rows = load_lasttest_naive()[:ROWS]
    t = [T0 + i * PERIOD_S for i in range(ROWS)]
    q = [[float(v) for v in r[1:7]] for r in rows]
    meas = [[float(v) for v in r[7:14]] for r in rows]
    for i in PUSHED:
        meas[i][0] += 0.02
    return t, q, meas


def send_all(client: TwinClient, robot: str, t, q, meas) -> None:
    client.ready([robot])
    pub = client.joints(robot)
    for i in range(len(t)):
        pub.put(json.dumps(joint_message(t[i], q[i], meas[i])))


def alarm_incident(armtwin_bin, tmp_path: Path, recorder: str = ""):
    """The service streamed the pushed rows under ``[recorder]`` settings ``recorder``:
    (its one incident file, its `recorded` event, its `alarm` events, stamps, joints, measured)."""
    recordings = tmp_path / "recordings"
    proc = ArmtwinProcess(armtwin_bin, tmp_path, config(recordings, recorder=recorder), 300.0)
    proc.start()
    client = TwinClient(proc.endpoint)
    robot = "site/cell-1/ur10e"
    try:
        t, q, meas = stream()
        send_all(client, robot, t, q, meas)
        c = client.collector
        recorded = c.wait_message("events", robot, lambda m: m["kind"] == "recorded", 60.0)
        assert recorded is not None, (c.messages("events", robot), proc.logs())
        alarms = [m for m in c.messages("events", robot) if m["kind"] == "alarm"]
        assert wait_until(lambda: c.count("pose", robot) == ROWS, 30), c.count("pose", robot)
    finally:
        client.close()
        proc.stop()
    assert len(alarms) == 1, alarms
    files = sorted(recordings.rglob("*.mcap"))
    assert len(files) == 1, files
    return files[0], recorded, alarms, t, q, meas


def test_an_alarm_leaves_one_mcap_file_with_what_was_streamed(armtwin_bin, tmp_path):
    # Without the robot drawn: the file is then the reference's, byte for byte.
    path, recorded, alarms, t, q, meas = alarm_incident(armtwin_bin, tmp_path, "draw_robot = false")
    recordings, robot = tmp_path / "recordings", "site/cell-1/ur10e"
    t_alarm = alarms[0]["t"]
    assert t[PUSHED.start] < t_alarm < t[PUSHED.stop], t_alarm

    # The robot id is one directory, escaped; the name is the UTC time and the trigger.
    assert path.parent == recordings / "site%2Fcell-1%2Fur10e", path
    assert re.fullmatch(r"\d{8}T\d{6}\.\d{3}Z-alarm\.mcap", path.name), path.name
    detail = recorded["detail"]
    assert Path(detail["path"]) == path and detail["bytes"] == path.stat().st_size, detail
    assert (detail["from_s"], detail["until_s"]) == (t_alarm - PRE_S, t_alarm + POST_S), detail

    # Byte for byte the file the recorder wrote when it kept every record in memory as raw
    # doubles (tests/data/README.md): the blocks it keeps now come back exactly.
    reference = lzma.decompress((DATA / "recorder" / "ur10e_alarm_incident.mcap.xz").read_bytes())
    assert path.read_bytes() == reference, (path.stat().st_size, len(reference))

    channels, messages, metadata = read_mcap(path)
    assert channels == {topic: (name, "ros2msg", "cdr") for topic, name in TOPICS.items()}, channels
    meta = metadata["armtwin"]
    assert meta["robot"] == robot and meta["model"] == "ur10e" and meta["trigger"] == "alarm", meta
    assert meta["calibration_source"] == "nominal" and meta["armtwin_version"], meta
    assert float(meta["trigger_stamp_s"]) == t_alarm
    assert json.loads(meta["trigger_event"])["kind"] == "alarm"

    window = [i for i in range(ROWS) if t_alarm - PRE_S <= t[i] <= t_alarm + POST_S]
    assert len(window) == 3001, len(window)
    for topic in ("/joint_states", "/twin/pose", "/tcp_pose_broadcaster/pose", "/twin/deviation"):
        assert len(messages[topic]) == len(window), (topic, len(messages[topic]))
        stamps = [stamp_of(m.header) for _, m, _ in messages[topic]]
        assert stamps == [t[i] for i in window], topic
        assert [log_time for log_time, _, _ in messages[topic]] == [
            m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m, _ in messages[topic]
        ]
    assert messages["/twin/effort"] == []

    typestore = get_typestore(Stores.ROS2_HUMBLE)
    for (_, joint_state, raw), i in zip(messages["/joint_states"], window):
        assert list(joint_state.name) == [
            "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
            "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
        ]
        sent = struct.pack("<6d", *q[i])
        assert struct.pack("<6d", *joint_state.position) == sent, i
        again = typestore.deserialize_cdr(raw, "sensor_msgs/msg/JointState")
        assert struct.pack("<6d", *again.position) == sent, i
        assert list(joint_state.velocity) == [] and list(joint_state.effort) == []
    for (_, pose, _), i in zip(messages["/tcp_pose_broadcaster/pose"], window):
        p = pose.pose.position
        assert abs(p.x - meas[i][0]) < 1e-12 and abs(p.y - meas[i][1]) < 1e-12 and abs(p.z - meas[i][2]) < 1e-12
    pushed = [m.position_m for (_, m, _), i in zip(messages["/twin/deviation"], window) if i in PUSHED]
    assert pushed and min(pushed) > 0.015, min(pushed)

    [(log_time, log, _)] = messages["/rosout"]
    assert log.level == 30 and log.name == "armtwin" and seconds(log.stamp) == t_alarm
    assert json.loads(log.msg)["kind"] == "alarm"

    # `armtwin validate` reads the file as a bag of the robot: every joint sample paired with its
    # measured pose again, the same deviations as the file's (the twin's own, streamed live).
    out = tmp_path / "report"
    res = run_armtwin("validate", path, "--out", out)
    assert res.returncode == 0, res.stderr
    cumulative = json.loads((out / "report.json").read_text())["cumulative"]
    live = [m.position_m for _, m, _ in messages["/twin/deviation"]]
    assert cumulative["n"] == len(window), cumulative["n"]
    assert abs(cumulative["position"]["max"] - max(live)) <= 1e-12, (cumulative["position"], max(live))
    assert abs(cumulative["position"]["mae"] - sum(live) / len(live)) <= 1e-12


def rotation_of(q) -> np.ndarray:
    """The rotation matrix of a ``geometry_msgs/Quaternion``."""
    return Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()


def test_an_incident_file_draws_the_arm_whose_frames_compose_to_the_twin_pose(armtwin_bin, tmp_path):
    """Foxglove's 3D view of an incident: with the defaults, the file carries the robot's URDF on
    ``/robot_description`` (read by Pinocchio) and its link frames on ``/tf`` at every joint
    sample. Walking ``/tf`` from the tool up to the poses' frame gives the twin pose of the same
    sample to 1e-9 m, and so does Pinocchio's pose of the URDF at the sample's joints. The other
    topics hold what the file without the robot drawn holds."""
    path, _, alarms, _, _, _ = alarm_incident(armtwin_bin, tmp_path)
    channels, messages, metadata = read_mcap(path)
    drawn = {"/robot_description": "std_msgs/msg/String", "/tf": "tf2_msgs/msg/TFMessage"}
    assert channels == {topic: (name, "ros2msg", "cdr") for topic, name in {**TOPICS, **drawn}.items()}
    from_s = float(metadata["armtwin"]["from_s"])

    [(log_time, description, _)] = messages["/robot_description"]
    assert abs(log_time * 1e-9 - from_s) < 1e-6, (log_time, from_s)
    model = pin.buildModelFromXML(description.data)
    data = model.createData()
    tool = model.getFrameId("tool0")
    assert tool < len(model.frames) and model.nq == 6, description.data

    twin = messages["/twin/pose"]
    tfs = messages["/tf"]
    joints = messages["/joint_states"]
    assert len(tfs) == len(twin) == len(joints) > 2000, (len(tfs), len(twin))
    worst_tf_m = worst_tf_rotation = worst_pin_m = 0.0
    for (_, tf, _), (_, pose, _), (_, joint_state, _) in zip(tfs, twin, joints, strict=True):
        assert stamp_of(tf.transforms[0].header) == stamp_of(pose.header)
        parent_of = {t.child_frame_id: t for t in tf.transforms}
        frame, position, rotation = "tool0", np.zeros(3), np.eye(3)
        while frame != pose.header.frame_id:
            step = parent_of[frame].transform
            r = rotation_of(step.rotation)
            position = r @ position + [step.translation.x, step.translation.y, step.translation.z]
            rotation = r @ rotation
            frame = parent_of[frame].header.frame_id
        p = pose.pose.position
        expected = np.array([p.x, p.y, p.z])
        worst_tf_m = max(worst_tf_m, float(np.abs(position - expected).max()))
        worst_tf_rotation = max(worst_tf_rotation, float(np.abs(rotation - rotation_of(pose.pose.orientation)).max()))
        pin.framesForwardKinematics(model, data, np.array(joint_state.position))
        worst_pin_m = max(worst_pin_m, float(np.abs(data.oMf[tool].translation - expected).max()))
    print(f"/tf against /twin/pose over {len(tfs)} samples: {worst_tf_m:.2e} m, {worst_tf_rotation:.2e} "
          f"per rotation entry; Pinocchio's pose of /robot_description: {worst_pin_m:.2e} m")
    assert worst_tf_m <= 1e-9 and worst_tf_rotation <= 1e-9 and worst_pin_m <= 1e-9

    # Everything else is as without the robot drawn.
    reference = lzma.decompress((DATA / "recorder" / "ur10e_alarm_incident.mcap.xz").read_bytes())
    plain = tmp_path / "reference.mcap"
    plain.write_bytes(reference)
    print(f"file {path.stat().st_size} bytes drawn, {len(reference)} without")
    _, plain_messages, _ = read_mcap(plain)
    for topic in TOPICS:
        if topic != "/rosout":
            assert [raw for _, _, raw in messages[topic]] == [raw for _, _, raw in plain_messages[topic]], topic
    assert alarms[0]["t"] == json.loads(plain_messages["/rosout"][0][1].msg)["t"]


# The service under a file size limit (what a full disk does to a write, from the kernel, without
# root): SIGXFSZ ignored, so a write past it fails with EFBIG instead of killing the process.
LIMITED = (
    "import os, resource, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
    "resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[1]), int(sys.argv[1]))); "
    "os.execv(sys.argv[2], sys.argv[2:])"
)


def test_a_recorder_that_cannot_write_counts_it_and_loses_no_twin_sample(armtwin_bin, tmp_path):
    recordings = tmp_path / "recordings"
    http_port = free_port()
    proc = ArmtwinProcess(
        armtwin_bin, tmp_path, config(recordings, f'\n[http]\nlisten = "127.0.0.1:{http_port}"'), 300.0
    )
    # 256 KiB: the service's log stays under it, an incident file of 3 000 joint samples does not.
    proc.argv = [sys.executable, "-c", LIMITED, str(256 * 1024), *proc.argv]
    proc.start()
    client = TwinClient(proc.endpoint)
    robot = "r1"
    try:
        t, q, meas = stream()
        send_all(client, robot, t, q, meas)
        c = client.collector
        failed = c.wait_message("events", robot, lambda m: m["kind"] == "record_failed", 60.0)
        assert failed is not None, (c.messages("events", robot), proc.logs())
        assert "too large" in failed["detail"]["error"].lower(), failed
        assert wait_until(lambda: c.count("pose", robot) == ROWS, 30), c.count("pose", robot)
        # The last pair's deviation follows its pose.
        assert wait_until(lambda: c.count("deviation", robot) == ROWS, 10), c.count("deviation", robot)
        [(_, state)] = get_json(client.session, f"twin/state/{robot}")
        assert state["metrics"]["paired"] == ROWS, state
        assert metric(http_port, "armtwin_recorder_failures_total") == 1
        assert metric(http_port, "armtwin_recorder_files_total") == 0
        assert metric(http_port, "armtwin_recorder_ring_bytes") > 0
    finally:
        client.close()
        proc.stop()
    assert list(recordings.rglob("*.mcap*")) == [], "what the failed write left is removed"


def test_an_operator_records_behind_the_secured_router_and_a_dashboard_may_not(tmp_path, certs, armtwin_bin):
    with secured_fleet(tmp_path, certs, armtwin_bin, ["g1", "dashboard", "operator"]) as (router, sessions, _):
        dashboard, operator = sessions["dashboard"], sessions["operator"]
        assert wait_queryable(operator, "twin/admin/record/**"), router.logs()
        paired = stream_until_paired(Gateway(sessions["g1"], "r1"), router, dashboard, "r1", at_least=50)
        events = []
        dashboard.declare_subscriber("twin/events/r1", lambda s: events.append(json.loads(s.payload.to_bytes())))

        refused = list(dashboard.get("twin/admin/record/r1?post_s=0", timeout=5.0))
        assert refused == [], "the router drops a dashboard's record query"
        [reply] = list(operator.get("twin/admin/record/r1?pre_s=1;post_s=0", timeout=5.0))
        assert reply.ok is not None, reply.err.payload.to_string()
        answer = json.loads(reply.ok.payload.to_bytes())
        assert answer["trigger"] == "operator", answer
        assert abs(answer["until_s"] - answer["from_s"] - 1.0) < 1e-6, answer
        assert wait_until(lambda: any(e["kind"] == "recorded" for e in events), 20), events
        [recorded] = [e for e in events if e["kind"] == "recorded"]
        assert recorded["detail"]["path"] == answer["path"], (recorded, answer)
        files = list((tmp_path / "twin" / "recordings").rglob("*-operator.mcap"))
        assert [str(f) for f in files] == [answer["path"]], files
        _, messages, metadata = read_mcap(files[0])
        assert metadata["armtwin"]["trigger"] == "operator"
        assert 1 <= len(messages["/joint_states"]) <= paired
        time.sleep(0.5)
        assert len([e for e in events if e["kind"] == "recorded"]) == 1, "the dashboard's query recorded nothing"


def test_a_robot_that_sets_incidents_off_without_pause_takes_only_its_own_share(armtwin_bin, tmp_path):
    """r1's stamps jump 2 s each at 200 Hz (a gap incident every few samples, in source time);
    r2 streams calmly and its operator records twice, before and during the flood. r2's files
    are written and kept; r1 sets off a few incidents back to back, then one per post_s, and
    keeps at most its own share of files (robot_max_files = 3), taking nothing of r2's although
    the fleet's cap is small (max_files = 6)."""
    recordings = tmp_path / "recordings"
    extra = ""
    text = config(recordings, extra).replace(
        "[recorder]\n", "[recorder]\nmax_files = 6\nrobot_max_files = 3\ngap_s = 1.0\n")
    proc = ArmtwinProcess(armtwin_bin, tmp_path, text, 300.0)
    proc.start()
    client = TwinClient(proc.endpoint)
    try:
        calm = Gateway(client, "r2", rate_hz=200.0, rows=2000, start_t=T0)
        calm.start()
        assert wait_until(lambda: client.collector.count("pose", "r2") >= 100, 20.0)
        [first] = list(client.session.get("twin/admin/record/r2?pre_s=0.2;post_s=0", timeout=10.0))
        assert first.ok is not None, first.err.payload.to_string()

        client.ready(["r1"])
        flood = client.joints("r1")
        q = Gateway.Q
        sent = 0
        started = time.monotonic()
        while time.monotonic() - started < 4.0:
            flood.put(json.dumps({"t": T0 + 2.0 * sent, "q": q}))
            sent += 1
            time.sleep(0.005)
        [second] = list(client.session.get("twin/admin/record/r2?pre_s=0.2;post_s=0", timeout=10.0))
        assert second.ok is not None, second.err.payload.to_string()
        calm.join(timeout=30)
        r2_paths = {json.loads(first.ok.payload.to_bytes())["path"], json.loads(second.ok.payload.to_bytes())["path"]}
        recorded = lambda robot: [e for e in client.collector.messages("events", robot) if e["kind"] == "recorded"]  # noqa: E731
        assert wait_until(lambda: len(recorded("r2")) == 2, 20.0), (client.collector.messages("events", "r2"), proc.logs())
        assert {e["detail"]["path"] for e in recorded("r2")} == r2_paths
        gaps = [e for e in client.collector.messages("events", "r1") if e["kind"] == "gap"]
        r1_incidents = len(recorded("r1"))
    finally:
        client.close()
        proc.stop()
    assert len(gaps) > 50, f"the flood set off {len(gaps)} gap events"
    # Four back to back, then one per post_s (2 s) over the 4-s flood, and its last at shutdown.
    assert 1 <= r1_incidents <= 8, f"r1 set off {r1_incidents} incidents from {len(gaps)} gaps"
    r1_files = list(recordings.glob("r1/*.mcap"))
    r2_files = sorted(str(f) for f in recordings.glob("r2/*.mcap"))
    assert len(r1_files) <= 3, r1_files
    assert r2_files == sorted(r2_paths), (r2_files, r2_paths)
    print(f"\n[fair recorder] {sent} flooding samples, {len(gaps)} gap events, {r1_incidents} incidents of r1 "
          f"({len(r1_files)} kept), r2's 2 files kept")


def test_an_operator_asks_for_an_incident_from_the_command_line(armtwin_bin, tmp_path):
    """`armtwin record --incident ROBOT` asks the twin as an operator's query does: it prints the
    twin's reply, whose file then appears; a robot the twin does not have is its refusal, in its
    words, and a non-zero exit."""
    recordings = tmp_path / "recordings"
    proc = ArmtwinProcess(armtwin_bin, tmp_path, config(recordings), 120.0)
    proc.start()
    client = TwinClient(proc.endpoint, subscribe=False)
    try:
        gateway = Gateway(client, "r1", rate_hz=200.0, rows=400, start_t=T0)
        gateway.start()
        assert wait_until(lambda: (get_json(client.session, "twin/state/r1") or [(None, {})])[0][1]
                          .get("metrics", {}).get("paired", 0) >= 100, 20.0)
        asked = run_armtwin("record", "--incident", "r1", "--pre-s", "0.2", "--post-s", "0", "-e", proc.endpoint)
        assert asked.returncode == 0, asked.stderr
        answer = json.loads(asked.stdout)
        assert answer["robot"] == "r1" and answer["trigger"] == "operator", answer
        assert abs(answer["until_s"] - answer["from_s"] - 0.2) < 1e-6, answer
        assert f"r1: incident file {answer['path']}" in asked.stderr, asked.stderr
        assert wait_until(lambda: Path(answer["path"]).exists(), 20.0), list(recordings.rglob("*"))
        assert Path(answer["path"]).parent.parent == recordings

        refused = run_armtwin("record", "--incident", "nobody", "-e", proc.endpoint)
        assert refused.returncode == 1, refused.stdout
        assert "the twin of 'nobody' refused:" in refused.stderr, refused.stderr
        wildcard = run_armtwin("record", "--incident", "r*", "-e", proc.endpoint)
        assert wildcard.returncode == 1 and "robots 'r*'" in wildcard.stderr, wildcard.stderr
        gateway.join(timeout=30)
    finally:
        client.close()
        proc.stop()
