"""`armtwin gateway rtde` against a stand-in UR controller (rtde_server.py), and the stand-in's bytes
checked by an independent RTDE client (ur-rtde).

No real controller or URSim runs here. The stand-in serves rows of the project's real UR10e
recording (tests/data/ur10e_lasttest.csv, converted by rtde_recording.py) faster than real time;
every process binds loopback only, ports are picked free, scouting is off, every wait is bounded.
A real UR3e's RTDE recording (tests/data/ur3e_rad_program.csv) served the same way shows what the
effort monitor watches collisions on, and with which thresholds, for a robot the gateway feeds.
"""

from __future__ import annotations

import csv
import json
import random
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from support import rtde_recording
from support.paths import DATA_DIR, SUPPORT_DIR
from support.process import free_port, run_armtwin, wait_until
from support.rtde_processes import Gateway, StandIn, serving
from support.zenoh_clients import reply_payloads

ROBOT = "cell-1/ur10e"
CONFIG = """\
[service]
metrics_period_ms = 50
pose_congestion = "block"

[robots.default]
model = "ur10e"
"""
STREAM_TIMEOUT_S = 60.0


# ----------------------------------------------------------------------------------------------
# processes
# ----------------------------------------------------------------------------------------------


@pytest.fixture
def service(armtwin_bin, tmp_path):
    with serving(armtwin_bin, tmp_path, CONFIG) as proc:
        yield proc


@pytest.fixture
def started(armtwin_bin, tmp_path, service):
    """Start stand-ins and gateways; every one is stopped after the test, gateways first."""
    stand_ins: list[StandIn] = []
    gateways: list[Gateway] = []

    def start(recording: Path, server_args=(), extra=(), ports=1, fleet=None):
        stand_in = StandIn(recording, *server_args, workdir=tmp_path, ports=ports)
        stand_ins.append(stand_in)
        if fleet is None:
            args = ["--host", "127.0.0.1", "--port", stand_in.ports[0], "--robot", ROBOT, *extra]
        else:
            args = ["-c", fleet(stand_in.ports)]
        gateway = Gateway(armtwin_bin, tmp_path, service.endpoint, *args)
        gateways.append(gateway)
        return stand_in, gateway

    yield start
    codes = [gateway.stop().code for gateway in gateways]
    for stand_in in stand_ins:
        stand_in.stop()
    assert codes == [0] * len(codes), f"a gateway did not stop cleanly: {codes}\n{gateways[0].logs()}"


def state(service, robot: str) -> dict | None:
    oks, _ = reply_payloads(service.session.get(f"twin/state/{robot}", timeout=5.0))
    return oks[0][1] if oks else None


def metrics_when(service, robot: str, predicate, timeout: float = STREAM_TIMEOUT_S) -> dict:
    """The robot's metrics (from its state answer) once ``predicate`` holds, or the last seen."""
    last: dict = {}

    def check():
        nonlocal last
        answer = state(service, robot)
        last = (answer or {}).get("metrics") or {}
        return bool(last) and predicate(last)

    wait_until(check, timeout, interval=0.1)
    return last


def paired_at_least(n: int):
    return lambda metrics: metrics.get("paired", 0) >= n


# ----------------------------------------------------------------------------------------------
# recordings
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def lasttest_rows():
    return rtde_recording.rtde_rows(DATA_DIR / "ur10e_lasttest.csv")


def recording(tmp_path: Path, rows, name="rows.csv", header=rtde_recording.HEADER) -> Path:
    return rtde_recording.write(rows, tmp_path / name, header)


def validate_cumulative(path: Path, tmp_path: Path) -> dict:
    out = tmp_path / f"validate-{path.stem}"
    result = run_armtwin("validate", path, "--out", out)
    assert result.returncode == 0, result.stderr
    return json.loads((out / "report.json").read_text())


# ----------------------------------------------------------------------------------------------
# the stand-in checked by ur-rtde
# ----------------------------------------------------------------------------------------------

READBACK = ["timestamp", "actual_q", "actual_TCP_pose", "robot_mode", "safety_mode", "robot_status_bits",
            "speed_scaling", "payload", "payload_cog", "joint_mode", "actual_digital_input_bits",
            "joint_temperatures"]


def test_the_stand_in_is_read_back_by_ur_rtde_bit_for_bit(tmp_path, lasttest_rows):
    """ur-rtde only connects to port 30004: both run in a private network namespace of their own
    (``unshare -rn``), where that port is free whatever else runs on this machine."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        pytest.fail("unshare and ip (util-linux, iproute2) are needed to give ur-rtde its port 30004")
    rng = random.Random(25)
    header = list(rtde_recording.HEADER) + ["robot_mode", "safety_mode", "robot_status_bits", "speed_scaling",
                                            "payload"]
    header += [f"payload_cog_{j}" for j in range(3)] + [f"joint_mode_{j}" for j in range(6)]
    header += ["actual_digital_input_bits"] + [f"joint_temperatures_{j}" for j in range(6)]
    rows = []
    for index, row in enumerate(lasttest_rows[:400:4]):
        rows.append([1.0 + index * 0.02, *row[1:],
                     rng.randint(-1, 7), rng.randint(-2**31, 2**31 - 1), rng.randint(0, 2**32 - 1),
                     rng.random(), rng.uniform(0, 20), *(rng.uniform(-1, 1) for _ in range(3)),
                     *(rng.randint(-2**31, 2**31 - 1) for _ in range(6)), rng.randint(0, 2**64 - 1),
                     *(rng.uniform(20, 60) for _ in range(6))])
    path = recording(tmp_path, rows, header=header)
    ready = tmp_path / "server.out"
    # The server ends by itself (timeout) even if this shell is killed; the reader starts once the
    # server says it listens (at most 10 s).
    script = (
        "ip link set lo up && "
        f"timeout 50 {sys.executable} {SUPPORT_DIR / 'rtde_server.py'} --port 30004 --recording {path} --rate-hz 50 "
        f"> {ready} & "
        "server=$!; "
        f"for i in $(seq 100); do grep -q listening {ready} && break; sleep 0.1; done; "
        f"timeout 30 {sys.executable} {SUPPORT_DIR / 'rtde_readback.py'} 500 20 {' '.join(READBACK)}; "
        "code=$?; kill $server; exit $code"
    )
    result = subprocess.run(["unshare", "-rn", "sh", "-c", script], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    lines = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    assert len(lines) >= 20, result.stdout + result.stderr
    by_timestamp = {row[0]: row for row in rows}
    widths = {"actual_q": 6, "actual_TCP_pose": 6, "payload_cog": 3, "joint_mode": 6, "joint_temperatures": 6}
    for line in lines:
        row = by_timestamp[float.fromhex(line["timestamp"])]
        at = 1
        for name in READBACK[1:]:
            width = widths.get(name, 1)
            served = row[at:at + width]
            at += width
            got = line["values"][name]
            got = got if isinstance(got, list) else [got]
            got = [float.fromhex(v) if isinstance(v, str) else v for v in got]
            for s, g in zip(served, got, strict=True):
                if isinstance(s, float):
                    assert s.hex() == g.hex(), (name, s, g)
                else:
                    assert s == g, (name, s, g)


# ----------------------------------------------------------------------------------------------
# the gateway
# ----------------------------------------------------------------------------------------------


def test_a_recording_through_the_gateway_twins_every_row_as_validate_does(
    tmp_path, lasttest_rows, service, started
):
    path = recording(tmp_path, lasttest_rows)
    recorded = tmp_path / "recorded.csv"
    _, gateway = started(path, ["--fast"], ["--record", recorded])
    n = len(lasttest_rows)
    metrics = metrics_when(service, ROBOT, paired_at_least(n))
    assert metrics.get("paired") == n, (metrics, gateway.logs())
    assert metrics.get("rejected") == 0, metrics
    expected = validate_cumulative(path, tmp_path)["cumulative"]
    assert metrics["cumulative"]["n"] == expected["n"] == n
    for name, stats in expected.items():
        if name == "n":
            continue
        for stat in ("mae", "rmse", "max"):
            got, want = metrics["cumulative"][name][stat], stats[stat]
            if name in ("position", "x", "y", "z"):
                assert got == want, (name, stat, got, want)
            else:
                # The joint message carries a quaternion, normalised again when decoded; validate
                # turns the rotation vector into one directly: the last bits may differ.
                assert got == pytest.approx(want, rel=1e-12), (name, stat, got, want)
    assert "streaming" in gateway.logs()
    # The stand-in has nothing but these columns: the others are dropped with one warning.
    assert gateway.logs().count("does not have these variables") == 1, gateway.logs()
    assert "joint_temperatures" in gateway.logs()
    # --record wrote ur_rtde's form, which validate reads to the same figures.
    assert gateway.stop().code == 0, gateway.logs()
    assert recorded.read_text().splitlines()[0] == ",".join(rtde_recording.HEADER)
    assert validate_cumulative(recorded, tmp_path)["cumulative"] == expected


def gaps(service) -> list[dict]:
    return [e for e in service.events if e.get("kind") == "gap" and e.get("robot") == ROBOT]


def test_a_dropped_link_is_reconnected_and_the_missed_time_is_a_gap(tmp_path, lasttest_rows, service, started):
    rows = lasttest_rows[:4000]
    # The link drops after 1500 rows; the controller's clock runs on 250 rows (0.5 s) meanwhile.
    _, gateway = started(recording(tmp_path, rows), ["--fast", "--drop-after", 1500, "--skip-on-drop", 250])
    metrics = metrics_when(service, ROBOT, paired_at_least(len(rows) - 250))
    assert metrics.get("paired") == len(rows) - 250, (metrics, gateway.logs())
    assert metrics.get("rejected") == 0, metrics
    assert wait_until(lambda: gaps(service), 5.0), service.events
    gap = gaps(service)[0]["detail"]
    assert gap["gap_s"] == pytest.approx(251 * 0.002, abs=1e-6), gap
    logs = gateway.logs()
    assert "link to the controller ended; reconnecting" in logs and logs.count("streaming") >= 2, logs


def test_a_controller_restart_continues_the_stamps_without_lockout(tmp_path, lasttest_rows, service, started):
    rows = lasttest_rows[:4000]
    _, gateway = started(recording(tmp_path, rows), ["--fast", "--restart-after", 2000])
    metrics = metrics_when(service, ROBOT, paired_at_least(len(rows)))
    assert metrics.get("paired") == len(rows), (metrics, gateway.logs())
    assert metrics.get("rejected") == 0, (metrics, service.events)
    assert "the controller's clock went back: it restarted" in gateway.logs()
    assert not [e for e in service.events if e.get("kind") == "rejected"], service.events


def test_a_controller_without_the_tcp_pose_streams_joints_only(tmp_path, lasttest_rows, service, started):
    rows = [row[:7] for row in lasttest_rows[:1000]]
    poses = []
    subscriber = service.session.declare_subscriber(f"twin/pose/{ROBOT}", poses.append)
    try:
        _, gateway = started(recording(tmp_path, rows, header=rtde_recording.HEADER[:7]), ["--fast"])
        assert wait_until(lambda: len(poses) >= len(rows), 30.0), (len(poses), gateway.logs())
    finally:
        subscriber.undeclare()
    metrics = metrics_when(service, ROBOT, lambda m: True)
    assert metrics.get("paired") == 0 and metrics.get("rejected") == 0, metrics
    assert len(poses) == len(rows)
    assert "actual_TCP_pose" in gateway.logs()


def test_a_controller_without_joint_angles_is_retried_and_never_ends_the_gateway(
    tmp_path, lasttest_rows, service, started
):
    header = ["timestamp"] + rtde_recording.HEADER[7:]
    rows = [[row[0], *row[7:]] for row in lasttest_rows[:100]]
    _, gateway = started(recording(tmp_path, rows, header=header), ["--fast"])
    assert wait_until(lambda: gateway.logs().count("does not know 'actual_q'") >= 2, 10.0), gateway.logs()
    assert gateway.proc.poll() is None


@pytest.mark.parametrize(
    ("damage", "said"),
    [
        ("size", "DATA_PACKAGE payload of"),
        ("recipe", "data package of recipe 2, expected recipe 1"),
        ("header", "frame size 1 is smaller than the 3-byte header"),
        ("type", "unexpected package 'Z'"),
        ("garbage", "error="),
    ],
)
def test_damaged_frames_end_the_link_not_the_gateway(tmp_path, lasttest_rows, service, started, damage, said):
    rows = lasttest_rows[:3000]
    _, gateway = started(recording(tmp_path, rows), ["--rate-hz", 2000, "--damage", damage, "--damage-after", 500])
    # The stream goes on after the reconnection: rows from the end of the recording arrive.
    last_t = None

    def reached_end():
        nonlocal last_t
        metrics = (state(service, ROBOT) or {}).get("metrics") or {}
        last_t = metrics.get("paired", 0)
        return last_t >= 2000

    assert wait_until(reached_end, 30.0, interval=0.1), (last_t, gateway.logs())
    # The damaged frame ends a link with its reason. A loaded machine's stand-in can also fall
    # silent past the gateway's 1-s bound first, which ends a link of its own.
    ended = [line for line in gateway.logs().splitlines() if "reconnecting" in line]
    assert any(said in line for line in ended), gateway.logs()
    assert gateway.proc.poll() is None
    metrics = metrics_when(service, ROBOT, lambda m: True)
    assert metrics.get("rejected") == 0, metrics


def test_twenty_controllers_from_one_gateway(tmp_path, lasttest_rows, service, started):
    rows = lasttest_rows[:500]
    robots = [f"plant/cell-{k}/ur10e" for k in range(20)]

    def fleet(ports):
        path = tmp_path / "gateways.toml"
        path.write_text("".join(
            f'[[controllers]]\nrobot = "{robot}"\nhost = "127.0.0.1"\nport = {port}\n\n'
            for robot, port in zip(robots, ports, strict=True)
        ))
        return path

    _, gateway = started(recording(tmp_path, rows), ["--fast"], ports=20, fleet=fleet)
    for robot in robots:
        metrics = metrics_when(service, robot, paired_at_least(len(rows)))
        assert metrics.get("paired") == len(rows), (robot, metrics, gateway.logs()[-3000:])
    assert gateway.logs().count("gateway rtde started") == 1


def test_a_controller_that_comes_up_late_is_streamed_once_it_does(
    armtwin_bin, tmp_path, lasttest_rows, service
):
    port = free_port()
    gateway = Gateway(armtwin_bin, tmp_path, service.endpoint, "--host", "127.0.0.1", "--port", port,
                      "--robot", ROBOT)
    stand_in = None
    try:
        # Refused, retried with a growing wait, never given up.
        assert wait_until(lambda: gateway.logs().count("cannot connect") >= 3, 10.0), gateway.logs()
        waits = [float(word.split("=")[1]) for line in gateway.logs().splitlines() if "cannot connect" in line
                 for word in line.split() if word.startswith("retry_in_s=")]
        assert waits[:3] == [0.1, 0.2, 0.4], waits
        stand_in = StandIn(recording(tmp_path, lasttest_rows[:500]), "--port", port, "--fast", workdir=tmp_path,
                           ports=0)
        metrics = metrics_when(service, ROBOT, paired_at_least(500), timeout=20.0)
        assert metrics.get("paired") == 500, (metrics, gateway.logs())
        assert gateway.stop().code == 0, gateway.logs()
    finally:
        gateway.stop()
        if stand_in is not None:
            stand_in.stop()


# ----------------------------------------------------------------------------------------------
# effort on a real UR3e's currents
# ----------------------------------------------------------------------------------------------

# 35.5 s of a real UR3e over RTDE at 25 Hz, target_current among its columns (tests/data/README.md).
UR3E_RECORDING = DATA_DIR / "ur3e_rad_program.csv"
# 10 % of each UR3e joint's largest torque (N·m): the rated-torque share of docs/load-twin.md.
UR3E_RATED_SHARE_NM = [5.4, 5.4, 2.8, 0.9, 0.9, 0.9]
FIXED_NM = [20.0, 20.0, 10.0, 3.0, 3.0, 3.0]
EFFORT_CONFIG = """\
[service]
metrics_period_ms = 50
pose_congestion = "block"
{effort}
[robots.default]
model = "ur3e"
effort = true

[robots."cell-1/ur3e-fixed"]
collision_threshold_nm = {fixed}
"""


def ur3e_rtde_recording(tmp_path: Path) -> tuple[Path, int]:
    """The UR3e recording as a controller serves it (its ``wall_clock`` column is the recording
    host's, no RTDE variable), and its number of rows."""
    with open(UR3E_RECORDING, newline="") as handle:
        rows = list(csv.reader(handle))
    kept = [index for index, name in enumerate(rows[0]) if name != "wall_clock"]
    path = tmp_path / "ur3e.csv"
    with open(path, "w", newline="") as handle:
        csv.writer(handle).writerows([[row[index] for index in kept] for row in rows])
    return path, len(rows) - 1


@pytest.mark.parametrize("threshold_learning_s", [None, 0.0], ids=["built-in", "unlearnt"])
def test_a_ur3e_through_the_gateway_has_collisions_watched_on_its_target_current(
    armtwin_bin, tmp_path, threshold_learning_s
):
    # What docs/ur-rtde.md and docs/load-twin.md say a robot fed by the gateway gets: collisions
    # on measured less target current, thresholds learnt unless the robot fixes its own (twice the
    # rated share meanwhile: 35.5 s is shorter than the built-in 60 s of learning), the rated
    # share itself with threshold_learning_s = 0.
    effort = "" if threshold_learning_s is None else f"[effort]\nthreshold_learning_s = {threshold_learning_s}\n"
    config = EFFORT_CONFIG.format(effort=effort, fixed=FIXED_NM)
    path, n = ur3e_rtde_recording(tmp_path)
    robots = ["cell-1/ur3e", "cell-1/ur3e-fixed"]
    readouts = {robot: 0 for robot in robots}

    def count(sample):
        robot = str(sample.key_expr).removeprefix("twin/effort/")
        readouts[robot] = readouts.get(robot, 0) + 1

    stand_ins, gateways = [], []
    with serving(armtwin_bin, tmp_path, config) as service:
        subscriber = service.session.declare_subscriber("twin/effort/**", count)
        try:
            for robot in robots:
                stand_ins.append(StandIn(path, "--fast", workdir=tmp_path))
                gateways.append(Gateway(armtwin_bin, tmp_path, service.endpoint, "--host", "127.0.0.1",
                                        "--port", stand_ins[-1].ports[0], "--robot", robot))
            assert wait_until(lambda: all(readouts[robot] >= n for robot in robots), STREAM_TIMEOUT_S), (
                readouts, gateways[0].logs()[-3000:])
            collision = {robot: state(service, robot)["effort"]["collision"] for robot in robots}
        finally:
            subscriber.undeclare()
            codes = [gateway.stop().code for gateway in gateways]
            for stand_in in stand_ins:
                stand_in.stop()
    assert codes == [0] * len(codes), codes
    assert readouts == {robot: n for robot in robots}, readouts
    learnt, fixed = collision["cell-1/ur3e"], collision["cell-1/ur3e-fixed"]
    assert learnt["detection"] == fixed["detection"] == "target_current", collision
    if threshold_learning_s is None:
        assert learnt["threshold_source"] == "learning", learnt
        assert learnt["threshold_nm"] == pytest.approx([2 * nm for nm in UR3E_RATED_SHARE_NM], rel=1e-12)
    else:
        assert learnt["threshold_source"] == "rated", learnt
        assert learnt["threshold_nm"] == pytest.approx(UR3E_RATED_SHARE_NM, rel=1e-12)
    assert fixed["threshold_source"] == "configured", fixed
    assert fixed["threshold_nm"] == FIXED_NM, fixed


def test_a_recording_is_appended_to_across_restarts_and_another_file_is_left_alone(
    tmp_path, lasttest_rows, service, started
):
    """`--record` of a restarted gateway appends under the header the file has, never truncates;
    a file whose columns are not this controller's is left byte for byte as it was."""
    # Each run's controller streams rows of its own: a truncated file would not begin with the
    # first run's.
    paths = [recording(tmp_path, lasttest_rows[:300], name="first.csv"),
             recording(tmp_path, lasttest_rows[300:600], name="second.csv")]
    recorded = tmp_path / "recorded.csv"
    runs = []
    for path in paths:
        _, gateway = started(path, ["--fast"], ["--record", recorded])
        before = len(runs[-1]) if runs else 1
        assert wait_until(lambda: recorded.exists() and len(recorded.read_text().splitlines()) > before + 10,
                          STREAM_TIMEOUT_S), gateway.logs()
        assert gateway.stop().code == 0, gateway.logs()
        runs.append(recorded.read_text().splitlines())
        assert runs[-1].count(",".join(rtde_recording.HEADER)) == 1, runs[-1][:3]
    # The second run's rows follow the first's, which are as they were.
    assert runs[1][:len(runs[0])] == runs[0] and len(runs[1]) > len(runs[0]), (len(runs[0]), len(runs[1]))
    assert "appending to the recording an earlier run wrote" in gateway.logs()

    other = tmp_path / "other.csv"
    other.write_text("timestamp,something_else\n1.0,2.0\n")
    before = other.read_bytes()
    _, gateway = started(paths[0], ["--fast"], ["--record", other])
    assert wait_until(lambda: "left as it is, not recording" in gateway.logs(), STREAM_TIMEOUT_S), gateway.logs()
    assert gateway.stop().code == 0, gateway.logs()
    assert other.read_bytes() == before
