"""``[service] outputs = "paired"`` (docs/protocol/messages.md, "Twin pose with its deviation"):
the same inputs into a service with separate outputs and one with paired outputs, in JSON and in
binary; every paired message holds exactly the twin pose and the deviation the separate streams
carry, and each layout of measured poses costs the messages the page says. Binary messages are read
with eclipse-zenoh's own ``z_deserialize``.

Run: ``.venv/bin/python -m pytest tests/python/test_paired_outputs.py -q``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import zenoh
from zenoh.ext import UInt64, z_deserialize

from support.checks import Checks
from support.process import ArmtwinProcess, wait_until
from support.twin_reference import MEASURED_KEYS, joint_message, load_fmpy
from support.zenoh_clients import PREFIX, EncodingCollector, TwinClient

WATCHDOG_S = 180.0
POSE_KEYS = ("x", "y", "z", "roll", "pitch", "yaw", "qx", "qy", "qz", "qw")
DEVIATION_KEYS = ("dx", "dy", "dz", "position", "quat_distance", "angle", "droll", "dpitch", "dyaw")
PERIOD_S = 0.1

# Each robot's measured poses come another way: in the joint message, on their own key after
# their joint sample, on their own key stamped between two joint samples, or not at all.
EMBEDDED, AFTER, BETWEEN, NONE = "embedded", "after", "between", "none"
ROBOTS = (EMBEDDED, AFTER, BETWEEN, NONE)


def config(encoding: str, outputs: str) -> str:
    return f"""\
[service]
metrics_period_ms = 50
# Every message is counted: a test client that falls behind must slow the twin, not miss any.
pose_congestion = "block"
encoding = "{encoding}"
outputs = "{outputs}"

[robots.default]
model = "ur10e"
"""


def send(client: TwinClient, q, meas) -> None:
    """The same samples for every robot, in the order a gateway of each layout sends them."""
    for i in range(len(q)):
        t = i * PERIOD_S
        measured = {k: float(v) for k, v in zip(MEASURED_KEYS, meas[i])}
        client.put_json(client.joints(EMBEDDED), joint_message(t, q[i], meas[i]))
        client.put_json(client.joints(AFTER), {"t": t, "q": [float(v) for v in q[i]]})
        client.put_json(client.measured(AFTER), {"t": t, **measured})
        client.put_json(client.joints(BETWEEN), {"t": t, "q": [float(v) for v in q[i]]})
        client.put_json(client.measured(BETWEEN), {"t": t + PERIOD_S / 2, **measured})
        client.put_json(client.joints(NONE), {"t": t, "q": [float(v) for v in q[i]]})


def decode_pose(item, binary: bool):
    """(t, seq, pose values) of a twin pose message."""
    if binary:
        t, seq, pose = z_deserialize(tuple[float, UInt64, list[float]], zenoh.ZBytes(item.payload))
        return t, int(seq), tuple(pose)
    m = item.json()
    return m["t"], m["seq"], tuple(m[k] for k in POSE_KEYS)


def decode_deviation(item, binary: bool):
    """(t, deviation values) of a deviation message."""
    if binary:
        t, d = z_deserialize(tuple[float, list[float]], zenoh.ZBytes(item.payload))
        return t, tuple(d)
    m = item.json()
    return m["t"], tuple(m[k] for k in DEVIATION_KEYS)


def decode_paired(item, binary: bool):
    """(t, seq, pose values, deviation values or None) of a paired message."""
    if binary:
        t, seq, pose, d = z_deserialize(
            tuple[float, UInt64, list[float], list[float]], zenoh.ZBytes(item.payload)
        )
        return t, int(seq), tuple(pose), (tuple(d) if d else None)
    m = item.json()
    keys = {"robot", "t", "seq", "frame", *POSE_KEYS, *DEVIATION_KEYS}
    assert set(m) <= keys, sorted(set(m) - keys)
    deviation = tuple(m[k] for k in DEVIATION_KEYS) if "dx" in m else None
    return m["t"], m["seq"], tuple(m[k] for k in POSE_KEYS), deviation


def run_service(armtwin_bin, workdir: Path, encoding: str, outputs: str, q, meas):
    """A service with `outputs`, fed every robot's samples; its collector once every robot's
    measured poses are counted in its metrics (the outputs of a step go out before the metrics
    that count it)."""
    workdir.mkdir()
    proc = ArmtwinProcess(armtwin_bin, workdir, config(encoding, outputs), WATCHDOG_S).start()
    client = TwinClient(proc.endpoint)
    try:
        client.subscriber.undeclare()
        client.collector = EncodingCollector()
        client.subscriber = client.session.declare_subscriber(f"{PREFIX}/**", client.collector)
        client.ready(ROBOTS, measured=True)
        send(client, q, meas)
        c = client.collector
        expected = {EMBEDDED: len(q), AFTER: len(q), BETWEEN: len(q) - 1, NONE: 0}

        last_t = {r: (len(q) - 1) * PERIOD_S + (PERIOD_S / 2 if r == BETWEEN else 0.0) for r in ROBOTS}

        def done():
            metrics = {r: c.last("metrics", r) or {} for r in ROBOTS}
            return all(
                metrics[r].get("paired") == paired and metrics[r].get("t") == pytest.approx(last_t[r])
                for r, paired in expected.items()
            )

        assert wait_until(done, 60), {r: c.last("metrics", r) for r in ROBOTS}
        # The `after` robot's last pose went out with its measured pose, before these metrics.
        return c, proc.logs()
    finally:
        client.close()
        code, _ = proc.stop()
        assert code == 0, proc.logs()


@pytest.mark.parametrize("encoding", ["json", "zenoh-serialized"])
def test_paired_messages_carry_exactly_the_separate_streams_poses_and_deviations(armtwin_bin, tmp_path, encoding):
    binary = encoding == "zenoh-serialized"
    q, meas = load_fmpy()
    n = len(q)
    separate, _ = run_service(armtwin_bin, tmp_path / "separate", encoding, "separate", q, meas)
    paired, logs = run_service(armtwin_bin, tmp_path / "paired", encoding, "paired", q, meas)

    checks = Checks()
    for robot in ROBOTS:
        poses = {}
        for item in separate.items("pose", robot):
            t, seq, pose = decode_pose(item, binary)
            poses[seq] = (t, pose)
        deviations = dict(decode_deviation(i, binary) for i in separate.items("deviation", robot))
        checks.equal(sorted(poses), list(range(n)), f"{robot}: separate pose seqs")
        checks.equal(separate.items("paired", robot), [], f"{robot}: separate service publishes nothing paired")

        messages = [decode_paired(i, binary) for i in paired.items("paired", robot)]
        paired_poses = {}
        paired_deviations = {}
        for t, seq, pose, deviation in messages:
            checks.equal(paired_poses.setdefault(seq, (t, pose)), (t, pose), f"{robot}: pose {seq} repeated as it was")
            if deviation is not None:
                paired_deviations[t] = deviation
        # Deviations paired outside their pose's message keep their own stream.
        fallback = dict(decode_deviation(i, binary) for i in paired.items("deviation", robot))
        checks.equal(paired.items("pose", robot), [], f"{robot}: no message on the pose stream")
        checks.equal(paired_poses, poses, f"{robot}: paired poses are the separate stream's, bit for bit")
        checks.equal({**paired_deviations, **fallback}, deviations, f"{robot}: deviations are the separate stream's")
        with_deviation = [m[3] is not None for m in messages]
        if robot == EMBEDDED:
            checks.equal(with_deviation, [True] * n, f"{robot}: one message per sample, each with its deviation")
            checks.equal(fallback, {}, f"{robot}: no deviation of its own")
        elif robot == AFTER:
            # The first pose goes out alone, then with its deviation; from then on each pose
            # waits for its measured pose.
            checks.equal(with_deviation, [False] + [True] * n, f"{robot}: pose alone once, then one message per sample")
            checks.equal([m[1] for m in messages], [0] + list(range(n)), f"{robot}: seqs")
            checks.equal(fallback, {}, f"{robot}: no deviation of its own")
        elif robot == BETWEEN:
            checks.equal(with_deviation, [False] * n, f"{robot}: poses alone")
            checks.equal(len(fallback), n - 1, f"{robot}: interpolated deviations on the deviation stream")
        else:
            checks.equal(with_deviation, [False] * n, f"{robot}: poses alone")
            checks.equal(deviations, {}, f"{robot}: no deviation")
    if binary:
        checks.equal(
            {k: v for k, v in paired.encodings.items() if k in ("pose", "deviation", "paired")},
            {"paired": {"zenoh/serialized;armtwin/paired/v1"}, "deviation": {"zenoh/serialized;armtwin/deviation/v1"}},
            "paired service's encodings",
        )
    checks.done(logs)
